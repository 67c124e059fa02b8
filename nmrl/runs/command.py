"""How a command ends: saved after a signal, refused by a lock, failed on the disk, or bad input.

Every nmrl command (``nmrl train``/``sweep``/``eval``: nmrl/cli/, ``nmrl study``, ``nmrl baseline``)
turns a failure that is not a bug into one line ``PROG: error: ...`` on stderr and an exit status
of nmrl/runs/exits.py the same way, here: :func:`failure` names another writer (6), the disk or
file system (5, through nmrl/runs/io_errors.py), memory (7) and a damaged metrics file (2);
:func:`exit_status` adds the command's own bad input (2); anything else is a bug and raises.
Nothing here imports JAX, so a command answers before JAX starts.

``nmrl study`` runs many sweeps under one signal guard (nmrl/runs/signals.py, :func:`run`): a
signal stops it after the chunk in flight with every active point saved, or, when the chunk is
still computing at the end of the grace (``NMRL_GRACE_S``, default 25 s), at once with the last
saved chunk kept.
"""

from __future__ import annotations

import os
import pathlib
import sys
from typing import Callable, Sequence

from nmrl.runs import errors, exits, io_errors, jsonl, lock, signals, store


def fail(prog: str, msg: str, status: int = exits.BAD_INPUT) -> int:
    """Print the one line ``PROG: error: MSG`` and return ``status`` (a disk failure's line through
    nmrl/runs/io_errors.py's ``report``, which keeps orbax's late tracebacks of it off stderr)."""
    line = f"{prog}: error: {msg}"
    if status == exits.IO_FAILED:
        io_errors.report(line)
    else:
        print(line, file=sys.stderr, flush=True)
    return status


def failure(prog: str, e: BaseException) -> int | None:
    """The one line (:func:`fail`) and exit status of a failure that is not a bug: another writer
    (6), the disk or file system (5: what was saved before is intact), memory (7), a damaged
    metrics file (2); None: another exception."""
    if isinstance(e, lock.Locked):
        return fail(prog, str(e), exits.LOCKED)
    if isinstance(e, io_errors.IOFailure):
        return fail(prog, str(e), exits.IO_FAILED)
    if isinstance(e, jsonl.Corrupt):
        return fail(prog, str(e))
    if isinstance(e, errors.OutOfMemory):
        return fail(prog, str(e), exits.OUT_OF_MEMORY)
    f = io_errors.find(e) if isinstance(e, (OSError, errors.CheckpointError)) else None
    if f is not None:
        return fail(prog, f"{f.line()}; what was saved before is intact: run the same command again once the cause "
                          f"is gone", exits.IO_FAILED)
    return None


def exit_status(prog: str, e: BaseException, bad_input: tuple[type[BaseException], ...]) -> int | None:
    """The exit status of the exception ``e`` that ends the command ``prog``, its line printed: a
    failure that is not a bug (:func:`failure`), else bad input (one of ``bad_input``, status 2);
    None: neither (the caller re-raises it, or knows more, e.g. a distributed run's lost peer)."""
    status = failure(prog, e)
    if status is None and isinstance(e, bad_input):
        status = fail(prog, str(e))
    return status


def run(prog: str, body: Callable[[], object], bad_input: tuple[type[BaseException], ...] = ()) -> int:
    """Run ``body()`` under a signal guard; return the command's exit status (module docstring).
    ``bad_input``: the command's own exception types that mean bad input (besides ValueError and
    the driver's and checkpoints' errors)."""
    guard = signals.Guard().install()
    try:
        guard.grace_s = signals.grace_of(None)  # a batch script's NMRL_GRACE_S, else the default
        body()
    except errors.Stopped as e:
        print(f"{prog}: {e}; every active point was saved; run the same command again to continue", file=sys.stderr)
        return e.exit_status
    except signals.Interrupted as e:
        return e.exit_status
    except Exception as e:  # noqa: BLE001 - another writer, the disk or file system; else bad input or a bug
        status = exit_status(prog, e, (ValueError, errors.RunError, errors.CheckpointError, *bad_input))
        if status is None:
            raise
        return status
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
