"""The exit statuses of every nmrl command, one table (docs/runs.md lists the same rows).

A script that drives nmrl decides from the status alone what happened and what to do next: fix
the command (2), pick other step sizes (3), restart the distributed run (4), free space or fix
permissions and run the same command again (5), wait for the other writer (6), run with smaller
sizes or on a larger machine (7), continue with ``--resume`` after a signal (130, 143).
This module must not import JAX (nmrl/cli/ reads it before JAX starts).
"""

from __future__ import annotations

import signal

DONE = 0
BAD_INPUT = 2
DIVERGED = 3
PEER_FAILED = 4  #: = nmrl.runs.launch.PEER_FAILED
IO_FAILED = 5  #: = nmrl.runs.io_errors.IO_FAILED
LOCKED = 6
OUT_OF_MEMORY = 7
SIGINT = 128 + int(signal.SIGINT)
SIGTERM = 128 + int(signal.SIGTERM)

#: status -> meaning (what is on disk afterwards)
TABLE: dict[int, str] = {
    DONE: "done (or nothing left to do)",
    BAD_INPUT: "bad input: one line `nmrl: error: ...` naming the value and what is allowed; nothing written",
    DIVERGED: "diverged: the last good checkpoint is kept",
    PEER_FAILED: "another process of a distributed run stopped or died; the newest checkpoint is intact, "
                 "continue with `--resume`",
    IO_FAILED: "the disk or file system refused a read or write (full, read-only, permission, immutable): one "
               "line naming the path and the cause; what was saved before is intact, no partial checkpoint is "
               "left, the same command continues once the cause is gone",
    LOCKED: "another nmrl process is writing the same directory (named: pid, command, start time); nothing "
            "written",
    OUT_OF_MEMORY: "the machine ran out of memory allocating the run (its sizes passed the pre-flight estimate); "
                   "nothing of the run is left",
    SIGINT: "stopped by SIGINT: after the chunk in flight was saved (`--resume` continues), or at the end of "
            "the grace with the last saved chunk kept, or before the first chunk with nothing of the run "
            "written; a second signal stops at once",
    SIGTERM: "stopped by SIGTERM, as for SIGINT",
}
