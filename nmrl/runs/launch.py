"""One process of a distributed ``nmrl train``/``nmrl sweep``, watched so that its failures read clearly.

JAX's multi-process runtime (nmrl/runs/distributed.py) does not raise when it cannot connect or
when another process dies: it aborts the process (SIGABRT) with a C++ log line and a stack trace
-- after ``initialization_timeout`` when the coordinator cannot be reached or a process never
comes, within seconds when a peer dies. So ``nmrl train --coordinator ...`` runs the real command
in a child process (same arguments, ``NMRL_DIST_CHILD=1``) and watches it:

* its stdout and stderr are passed through, without the stack-trace lines of an abort, gloo's
  "connected" line and the C++ runtime's log lines (``E1203 10:35:01.123456 12 file.cc:12] ...``:
  the coordination service's heartbeats and errors); those are kept and printed only when the child
  ends by a signal other than an abort (a crash they may explain);
* SIGINT/SIGTERM/SIGHUP are passed on once (the child is in its own session, so a terminal's
  Ctrl-C does not reach it twice), and the child gets SIGTERM if this process dies;
* an abort before the child printed :data:`CONNECTED` becomes "could not join the run" (exit 2,
  nothing was written: a process writes nothing before every process has connected); one after it
  becomes "another process failed" (exit :data:`PEER_FAILED`); any other exit status is passed on.

This module must not import JAX (the watcher stays small).
"""

from __future__ import annotations

import dataclasses
import os
import re
import signal
import subprocess
import sys
import threading

AUTO = "auto"
CHILD_ENV = "NMRL_DIST_CHILD"
#: Printed (stderr) by a process once every process has connected (nmrl.runs.distributed.initialize).
CONNECTED = "nmrl: distributed: connected"
DEFAULT_TIMEOUT_S = 120
#: Exit status of a process stopped because another process of its run failed.
PEER_FAILED = 4
#: stderr lines not passed on: an abort's stack trace, gloo's "Rank 0 is connected to 1 peer ranks"
_STACK = re.compile(r"^\s+@\s+0x[0-9a-f]+|^\*\*\* Check failure stack trace|^\[Gloo\] Rank \d+ is connected")
_FATAL = re.compile(r"^F\d{4} [\d:.]+\s+\d+ [^\]]+\] (.*)")
#: a line of the C++ runtime's log (absl/glog: severity, date, time, thread, file:line]) or absl's preamble
_NATIVE = re.compile(r"^[IWEF]\d{4} [\d:.]+\s+\d+ [^\]]+\] |^WARNING: All log messages before absl::InitializeLog")


@dataclasses.dataclass(frozen=True)
class Cluster:
    """Where a process stands in a distributed run (the command line's ``--coordinator`` options).

    ``coordinator`` is ``HOST:PORT`` of process 0's coordination service, or ``auto`` (JAX detects
    the cluster, e.g. SLURM; ``num_processes``/``process_id`` then come from it unless given).
    ``timeout_s`` is how long a process waits for the others: to connect, at a barrier, and before
    a silent peer is declared dead (JAX's heartbeat timeout).
    """

    coordinator: str
    num_processes: int | None = None
    process_id: int | None = None
    timeout_s: int = DEFAULT_TIMEOUT_S

    def validate(self) -> None:
        c = self.coordinator
        if c != AUTO:
            m = re.fullmatch(r"(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.\-]+):(\d+)", c or "")
            if not m or not 1 <= int(m.group(2)) <= 65535:
                raise ValueError(f"--coordinator={c!r} is invalid: give HOST:PORT (a port in 1..65535, e.g. "
                                 f"127.0.0.1:12345 or node001:12345) or 'auto' (detect the cluster, e.g. SLURM)")
            missing = [o for o, v in (("--num-processes", self.num_processes), ("--process-id", self.process_id))
                       if v is None]
            if missing:
                raise ValueError(f"--coordinator {c} needs {' and '.join(missing)} (or give --coordinator auto)")
        n, i = self.num_processes, self.process_id
        if n is not None and not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            raise ValueError(f"--num-processes={n!r} is invalid: must be an integer >= 1")
        if i is not None and not (isinstance(i, int) and not isinstance(i, bool) and i >= 0):
            raise ValueError(f"--process-id={i!r} is invalid: must be an integer >= 0")
        if n is not None and i is not None and i >= n:
            raise ValueError(f"--process-id={i} is invalid with --num-processes {n}: the ids are 0..{n - 1}")
        t = self.timeout_s
        if not (isinstance(t, int) and not isinstance(t, bool) and 1 <= t <= 86400):
            raise ValueError(f"--dist-timeout={t!r} is invalid: must be a whole number of seconds in [1, 86400]")

    def who(self) -> str:
        if self.process_id is None:
            return "this process"
        return f"process {self.process_id}" + (f" of {self.num_processes}" if self.num_processes else "")


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    try:
        import ctypes

        ctypes.CDLL(None).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    except Exception:  # noqa: BLE001 - not Linux: the child outlives a killed watcher
        pass


def supervise(argv: list[str], cluster: Cluster, out: str | None = None) -> int:
    """Run ``nmrl <argv>`` as this process of the run; returns the exit status to report."""
    env = dict(os.environ, **{CHILD_ENV: "1", "PYTHONUNBUFFERED": "1"})
    child = subprocess.Popen([sys.executable, "-m", "nmrl.cli", *argv], env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, errors="replace", bufsize=1,
                             start_new_session=True, preexec_fn=_die_with_parent)

    def pass_stdout() -> None:  # gloo prints its "connected" line to stdout: keep stdout the command's own
        assert child.stdout is not None
        for line in child.stdout:
            if not _STACK.match(line):
                sys.stdout.write(line)
                sys.stdout.flush()

    out_thread = threading.Thread(target=pass_stdout, daemon=True)
    out_thread.start()

    def forward(signum, _frame):
        try:
            child.send_signal(signum)
        except ProcessLookupError:
            pass

    old = {s: signal.signal(s, forward) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    connected, fatal, native = False, [], []
    try:
        assert child.stderr is not None
        for line in child.stderr:
            if _STACK.match(line):
                continue
            if line.startswith(CONNECTED):
                connected = True
            m = _FATAL.match(line)
            if m:
                fatal.append(m.group(1).strip())
            elif fatal and len(fatal) < 4 and line.strip():
                fatal.append(line.strip())  # the status lines after the fatal one (RPC, absl::Status)
            if _NATIVE.match(line) or fatal:  # the runtime's log and what follows an abort: kept back
                native.append(line)
                continue
            sys.stderr.write(line)
            sys.stderr.flush()
        rc = child.wait()
        out_thread.join(timeout=10)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if rc >= 0:
        return rc
    sig = -rc
    if sig != signal.SIGABRT and native:  # a crash: what the runtime said may explain it
        sys.stderr.writelines(native[-40:])
        sys.stderr.flush()
    reason = " ".join(fatal)[:600] or f"killed by signal {sig}"
    if sig == signal.SIGABRT and not connected:
        n = cluster.num_processes
        ids = f"distinct --process-id values 0..{n - 1}" if n else "distinct --process-id values"
        print(f"nmrl: error: {cluster.who()} could not join the run through the coordinator {cluster.coordinator} "
              f"within --dist-timeout {cluster.timeout_s} s (JAX: {reason}). Check that every process was started "
              f"with the same --coordinator and --num-processes and {ids}, that process 0 is running, and that the "
              f"coordinator's address is reachable from here (not firewalled, the port not taken); nothing was "
              f"written", file=sys.stderr, flush=True)
        return 2
    if sig == signal.SIGABRT:
        print(peer_failed_message(cluster.who(), f"JAX: {reason}", out), file=sys.stderr, flush=True)
        return PEER_FAILED
    return 128 + sig


def peer_failed_message(who: str, reason: str, out: str | None) -> str:
    """The error of a process stopped because another process of its run failed."""
    where = f" in {out}" if out else ""
    return (f"nmrl: error: another process of this distributed run stopped or died, so {who} was stopped too "
            f"({reason}). The newest checkpoint{where} is intact (saves are atomic); continue with --resume, "
            f"with any number of processes")
