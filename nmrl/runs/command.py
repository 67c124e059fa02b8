"""How a long command ends: saved after a signal, refused by a lock, failed on the disk, or bad input.

``nmrl study`` runs many sweeps under one signal guard (nmrl/runs/signals.py) and ends this way:
a signal stops it after the chunk in flight with
every active point saved; a second writer is refused naming the first; a disk or file-system
failure is one line (nmrl/runs/io_errors.py); bad input is one line with exit status 2; anything
else is a bug and raises. The statuses are nmrl/runs/exits.py's.
"""

from __future__ import annotations

import os
import pathlib
import sys
from typing import Callable, Sequence

from nmrl.runs import checkpoint, errors, exits, io_errors, lock, signals, store


def run(prog: str, body: Callable[[], object], bad_input: tuple[type[BaseException], ...] = ()) -> int:
    """Run ``body()`` under a signal guard; return the command's exit status (module docstring).
    ``bad_input``: the command's own exception types that mean bad input (besides ValueError and
    the driver's and checkpoints' errors)."""
    guard = signals.Guard().install()
    try:
        body()
    except errors.Stopped as e:
        print(f"{prog}: {e}; every active point was saved; run the same command again to continue", file=sys.stderr)
        return e.exit_status
    except signals.Interrupted as e:
        return e.exit_status
    except lock.Locked as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return exits.LOCKED
    except Exception as e:  # noqa: BLE001 - the disk or file system; else bad input or a bug
        f = io_errors.find(e) if isinstance(e, (OSError, checkpoint.CheckpointError, io_errors.IOFailure)) else None
        if isinstance(e, io_errors.IOFailure) or f is not None:
            io_errors.report(f"{prog}: error: {e if isinstance(e, io_errors.IOFailure) else f.line()}")
            return exits.IO_FAILED
        if isinstance(e, (ValueError, errors.RunError, checkpoint.CheckpointError) + tuple(bad_input)):
            print(f"{prog}: error: {e}", file=sys.stderr)
            return exits.BAD_INPUT
        raise
    finally:
        guard.restore()
    return 0


def study_dir(out: str | os.PathLike, phases: Sequence[str], allowed: Sequence[str],
              error: type[Exception] = ValueError) -> pathlib.Path:
    """A study command's directory, absolute, once its ``phases`` are among ``allowed`` (ValueError
    naming the others) and ``out`` is a path a command may write (nmrl.runs.store.out_path: not
    empty, not the root, not too long, not a file or below one; ``error`` naming it); nothing is
    created."""
    bad = [p for p in phases if p not in allowed]
    if bad:
        raise ValueError(f"unknown phase(s) {bad}: choose from {list(allowed)}")
    try:
        return store.out_path(out).absolute()
    except ValueError as e:
        raise error(str(e)) from None
