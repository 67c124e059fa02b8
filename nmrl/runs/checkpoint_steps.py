"""orbax's step directories of a run's checkpoints: listing, reading, the newest readable one.

A run's checkpoints are ``RUN_DIR/checkpoints/<step>/``, each written by orbax's
``CheckpointManager`` with the items of nmrl/runs/checkpoint_files.py (``ITEMS``). The manager is
opened synchronously and quietly: orbax's expected failures and an event-loop race of tensorstore
are kept off stderr (:func:`_quiet_absl`), so that a failure is the command's one line. Every
failure raises :class:`~nmrl.runs.errors.CheckpointError` naming the path
(:class:`~nmrl.runs.errors.CorruptCheckpoint` for a step that cannot be read).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import pathlib
import threading
import time
import weakref
from typing import Any, Iterator

import jax

from nmrl.runs.checkpoint_files import FORMAT, ITEMS, SCHEMA_VERSION, _err
from nmrl.runs.errors import CheckpointError, CorruptCheckpoint
from nmrl.runs.store import CHECKPOINTS

__all__ = ['checkpoint_dir', 'all_steps', 'latest_step', 'load_metadata', 'newest_good']


def checkpoint_dir(run_dir: str | os.PathLike) -> pathlib.Path:
    """The directory that holds the step directories of a run (absolute: orbax requires it)."""
    return pathlib.Path(run_dir).absolute() / CHECKPOINTS


def _ocp():
    # Imported lazily: orbax is heavy and evaluation-free code paths should not pay for it.
    import orbax.checkpoint as ocp

    return ocp


def _run_drained(coro: Any) -> Any:
    """orbax's ``_run_sync_via_new_loop`` that lets the loop finish every task before closing it.

    When one read of a damaged checkpoint fails, orbax closes its event loop while tensorstore
    still completes the other reads; their callbacks then hit the closed loop and print hundreds of
    lines of ``RuntimeError: Event loop is closed`` tracebacks to stderr, after the restore has
    already returned. Draining the loop first delivers them to an open loop (and retrieves their
    exceptions, so asyncio does not log "Task exception was never retrieved" either).
    """
    loop = asyncio.new_event_loop()
    try:
        asyncio.set_event_loop(loop)
        return loop.run_until_complete(coro)
    finally:
        try:
            pending = [t for t in asyncio.all_tasks(loop) if not t.done()]
            if pending:
                loop.run_until_complete(asyncio.wait(pending, timeout=120))
            for t in pending:
                if t.done() and not t.cancelled():
                    t.exception()
        except Exception:  # noqa: BLE001 - never mask the restore's own result or error
            pass
        finally:
            asyncio.set_event_loop(None)
            loop.close()


#: how long a failed orbax operation's own threads get to finish (and log) while the loggers are quiet
_SETTLE_S = 20.0


def _join_new_threads(before: set, timeout: float) -> list[threading.Thread]:
    """Wait (at most ``timeout`` s in all) for orbax's threads started since ``before`` was taken
    (its save and commit threads; a library's long-lived worker pools are not waited for).

    When a save fails (a full disk), orbax's other background threads of that save fail a moment
    later and log their exception with its traceback through absl; waiting for them while the
    loggers are still quiet keeps a failure to the command's one line. orbax's threads raise their own
    failure again from ``join``; that does not stop the wait for the others. Returns the threads still
    running at the deadline."""
    deadline = time.monotonic() + timeout
    started = [t for t in threading.enumerate()
               if t not in before and type(t).__module__.startswith("orbax") and t is not threading.current_thread()]
    for t in started:
        try:
            t.join(max(0.0, deadline - time.monotonic()))
        except Exception:  # noqa: BLE001 - orbax's threads re-raise their failure from join(): wait for the rest
            pass
    return [t for t in started if t.is_alive()]


class _FromThreads(logging.Filter):
    """Drops the records that the given threads log: a failed operation's stragglers."""

    def __init__(self, threads: list[threading.Thread]):
        super().__init__()
        self.threads = weakref.WeakSet(threads)

    def filter(self, record: logging.LogRecord) -> bool:
        return threading.current_thread() not in self.threads


@contextlib.contextmanager
def _quiet_absl() -> Iterator[None]:
    """Keep library noise off stderr while orbax runs.

    orbax logs expected failures (and a line per save) at ERROR/INFO through absl; and a failed
    read of a damaged checkpoint makes tensorstore print "Event loop is closed" tracebacks later
    (see :func:`_run_drained`, swapped in for orbax's loop runner while this context is active).
    When the body fails, the threads it started are given time to finish before the loggers speak
    again (:func:`_join_new_threads`); what those still running after that time log later is
    dropped (:class:`_FromThreads`), so a failure stays one line on a loaded machine too.
    """
    loggers = [logging.getLogger("absl"), logging.getLogger("orbax"), logging.getLogger("asyncio")]
    old = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        from orbax.checkpoint._src import asyncio_utils as _au
    except ImportError:  # pragma: no cover - another orbax layout: only the logging is quieted
        _au = None
    runner = getattr(_au, "_run_sync_via_new_loop", None)
    if runner is not None:
        _au._run_sync_via_new_loop = _run_drained
    before = set(threading.enumerate())
    try:
        yield
    except BaseException:
        stragglers = _join_new_threads(before, _SETTLE_S)
        if stragglers:  # still running on a loaded machine: whatever they log later stays off stderr
            for lg in loggers:
                lg.addFilter(_FromThreads(stragglers))
        raise
    finally:
        if runner is not None:
            _au._run_sync_via_new_loop = runner
        for lg, lv in zip(loggers, old):
            lg.setLevel(lv)


def _manager(directory: pathlib.Path, *, keep: int | None = None, read_only: bool = False,
             save_interval_steps: int | None = None):
    ocp = _ocp()
    extra: dict[str, Any] = {} if save_interval_steps is None else {"save_interval_steps": save_interval_steps}
    create = not read_only
    if jax.process_count() > 1:
        # A multi-process run (nmrl/runs/distributed.py): checkpoints hold host arrays gathered from
        # every process and only process 0 saves, so each process's manager works alone (no barriers).
        me = jax.process_index()
        extra["multiprocessing_options"] = ocp.options.MultiprocessingOptions(primary_host=me, active_processes={me})
        if create:
            directory.mkdir(parents=True, exist_ok=True)
        create = False
    opts = ocp.CheckpointManagerOptions(
        max_to_keep=keep,
        create=create,
        read_only=read_only,
        enable_async_checkpointing=False,
        cleanup_tmp_directories=not read_only,
        **extra,
    )
    return ocp.CheckpointManager(directory, options=opts, item_names=ITEMS)


# ----------------------------------------------------------------------------- listing


def _existing_dir(run_dir: str | os.PathLike) -> pathlib.Path:
    run = pathlib.Path(run_dir)
    if not run.is_dir():
        raise CheckpointError(f"{run}: run directory does not exist")
    d = checkpoint_dir(run)
    if not d.is_dir():
        raise CheckpointError(f"{d}: no checkpoints directory (nothing was saved in run {run})")
    return d


def all_steps(run_dir: str | os.PathLike) -> list[int]:
    """Steps of the finished checkpoints of a run, ascending ([] if none; CheckpointError if no run)."""
    d = _existing_dir(run_dir)
    try:
        with _quiet_absl(), _manager(d, read_only=True) as m:
            return sorted(int(s) for s in m.all_steps())
    except Exception as e:  # noqa: BLE001 - wrap every orbax failure
        raise _err(d, "cannot list checkpoints", e) from e


def latest_step(run_dir: str | os.PathLike) -> int | None:
    """The newest finished checkpoint's step, or None if the run has none."""
    d = _existing_dir(run_dir)
    try:
        with _quiet_absl(), _manager(d, read_only=True) as m:
            return m.latest_step()
    except Exception as e:  # noqa: BLE001 - wrap every orbax failure
        raise _err(d, "cannot list checkpoints", e) from e


def _resolve_step(run_dir: str | os.PathLike, step: int | None) -> tuple[pathlib.Path, int]:
    d = _existing_dir(run_dir)
    steps = all_steps(run_dir)
    if not steps:
        tmp = [p.name for p in d.iterdir() if ".orbax-checkpoint-tmp" in p.name]
        why = f" ({len(tmp)} unfinished save(s) left by an interrupted process)" if tmp else ""
        raise CheckpointError(f"{d}: contains no finished checkpoint{why}")
    if step is None:
        step = steps[-1]
    step = int(step)
    if step not in steps:
        raise CheckpointError(f"{d / str(step)}: no checkpoint at step {step}; available steps: {steps}")
    return d, step


def _restore_items(d: pathlib.Path, step: int, **args: Any) -> Any:
    ocp = _ocp()
    path = d / str(step)
    try:
        with _quiet_absl(), _manager(d, read_only=True) as m:
            return m.restore(step, args=ocp.args.Composite(**args))
    except Exception as e:  # noqa: BLE001
        items = ", ".join(args)
        raise _err(path, f"cannot read checkpoint item(s) {items} (truncated or corrupted?)", e,
                   CorruptCheckpoint) from e


def load_metadata(run_dir: str | os.PathLike, step: int | None = None) -> dict:
    """The JSON metadata of a checkpoint (the newest if ``step`` is None)."""
    d, step = _resolve_step(run_dir, step)
    path = d / str(step)
    meta = _restore_items(d, step, meta=_ocp().args.JsonRestore()).meta
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CorruptCheckpoint(f"{path}: not an nmrl checkpoint (metadata has no format={FORMAT!r})")
    if meta.get("schema") != SCHEMA_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint schema {meta.get('schema')!r} is not supported (this nmrl reads "
            f"schema {SCHEMA_VERSION})"
        )
    for k in ("config", "state_layout", "state_digest", "policy_digest", "model_sha256", "step"):
        if k not in meta:
            raise CorruptCheckpoint(f"{path}: checkpoint metadata lacks the field {k!r}")
    if not isinstance(meta["config"], dict):
        raise CorruptCheckpoint(f"{path}: the checkpoint metadata's config is not an object")
    try:
        saved_step = int(meta["step"])
    except (TypeError, ValueError):
        saved_step = None
    if saved_step != step:
        raise CorruptCheckpoint(f"{path}: metadata says step {meta['step']!r} but the directory is step {step}")
    meta["path"] = str(path)
    return meta



def newest_good(run_dir: str | os.PathLike, load: Any, step: int | None = None
                ) -> tuple[int, Any, list[CorruptCheckpoint]]:
    """``(step, load(step), skipped)``: ``load`` applied to the checkpoint ``step`` or, if None, to the
    newest one that is not corrupted.

    With ``step`` given every error propagates. Without, a :class:`CorruptCheckpoint` raised by
    ``load`` moves on to the next older checkpoint; ``skipped`` lists those errors, newest first
    (each names its path). Any other CheckpointError (another run, another model) propagates, and
    so does the newest error when no checkpoint is readable. Nothing on disk is changed.
    """
    d, newest = _resolve_step(run_dir, step)
    if step is not None:
        return newest, load(newest), []
    skipped: list[CorruptCheckpoint] = []
    for s in reversed(all_steps(run_dir)):
        try:
            return s, load(s), skipped
        except CorruptCheckpoint as e:
            skipped.append(e)
    if len(skipped) == 1:
        raise skipped[0]
    raise CorruptCheckpoint(f"{d}: none of the {len(skipped)} checkpoints is readable; the newest: {skipped[0]}")
