"""How the ``nmrl`` command turns an exception into its one line and exit status.

The mapping is nmrl/runs/command.py's, the one every nmrl command uses (``nmrl study`` and
``nmrl baseline`` too): another writer (6), the disk or file system (5), memory (7), a damaged
metrics file or bad input (2); here it is spoken as ``nmrl: error: ...``, and a distributed run
adds its own: another process of the run gone (4, nmrl/runs/launch.py). Anything else is a bug and
raises.
"""

from __future__ import annotations

import argparse
import sys

from nmrl.cli.cluster_options import cluster_of
from nmrl.runs import exits
from nmrl.runs import launch as _launch

PROG = "nmrl"


def fail(msg: str, status: int = exits.BAD_INPUT) -> int:
    """Print the one line ``nmrl: error: MSG`` and return ``status`` (command.fail)."""
    from nmrl.runs import command  # the run store's modules (numpy) after the signal guard

    return command.fail(PROG, msg, status)


def exit_status(args: argparse.Namespace, e: Exception, bad_input: tuple[type[BaseException], ...] = ()) -> int:
    """The exit status of the exception ``e`` that ends the command, its line printed: a failure that
    is not a bug (another writer, the disk, memory, a damaged metrics file), bad input (one of
    ``bad_input``; command.exit_status) or, in a distributed run, a process gone
    (:func:`peer_failure`); anything else is a bug and is re-raised."""
    from nmrl.runs import command

    status = command.exit_status(PROG, e, bad_input)
    if status is None:
        status = peer_failure(args, e)
    if status is None:
        raise e
    return status


def peer_failure(args: argparse.Namespace, e: BaseException) -> int | None:
    """The exit status for an exception that means another process of the run is gone (else None)."""
    if getattr(args, "coordinator", None) is None:
        return None
    from nmrl.runs import distributed

    if isinstance(e, distributed.PeerFailed) or distributed.is_peer_failure(e):
        print(_launch.peer_failed_message(cluster_of(args).who(), str(e).splitlines()[0][:400],
                                          args.out), file=sys.stderr, flush=True)
        return _launch.PEER_FAILED
    return None
