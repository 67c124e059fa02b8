"""The files of checkpoints: flat named arrays, digests, provenance, and orbax's step directories.

Shared by the full checkpoints (nmrl/runs/checkpoint.py), the run identity (nmrl/runs/identity.py),
the compact continuation states (nmrl/runs/compact.py) and other learners' trees
(nmrl/runs/trees.py): a pytree is saved as a flat dict of arrays named by its key paths
(``slots.env.data.qpos``), with its layout (shape, dtype per name) and a sha256 digest of the bytes;
provenance (library versions, the checkout's commit, the model file's sha256) is looked up once
per process; orbax's ``CheckpointManager`` is opened synchronously and quietly (its expected
failures and an event-loop race of tensorstore kept off stderr). Every failure a caller can meet
raises :class:`CheckpointError` naming the path (:class:`CorruptCheckpoint`: unreadable or not
matching its digest; :class:`ForeignCheckpoint`: of another run).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hashlib
import logging
import os
import pathlib
import platform
import re
import subprocess
import threading
import time
from typing import Any, Iterator

import jax
import numpy as np

import nmrl
from nmrl import learners
from nmrl.runs import store
from nmrl.runs.store import CHECKPOINTS

__all__ = ['CheckpointError', 'CorruptCheckpoint', 'ForeignCheckpoint', 'SCHEMA_VERSION', 'checkpoint_dir',
           'all_steps', 'latest_step', 'load_metadata', 'newest_good']

#: Version of the on-disk layout of a checkpoint; bump when it changes incompatibly.
SCHEMA_VERSION = 1
FORMAT = "nmrl-checkpoint"
ITEMS = ("state", "policy", "meta")

_SEP = "."
Params = Any
#: A learner's config (nmrl/learners/contract.py), its state and its trainer (the contract's Protocol).
Config = Any
State = Any
Trainer = learners.Trainer


class CheckpointError(Exception):
    """A checkpoint cannot be written, found, read or used; the message names the path and why."""


class CorruptCheckpoint(CheckpointError):
    """The checkpoint's files cannot be read, are truncated, or do not match their digest."""


class ForeignCheckpoint(CheckpointError):
    """The checkpoint belongs to another run: its config or model differs from the run's."""


# ----------------------------------------------------------------------------- helpers


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


def _join_new_threads(before: set, timeout: float) -> None:
    """Wait (at most ``timeout`` s in all) for orbax's threads started since ``before`` was taken
    (its save and commit threads; a library's long-lived worker pools are not waited for).

    When a save fails (a full disk), orbax's other background threads of that save fail a moment
    later and log their exception with its traceback through absl; waiting for them while the
    loggers are still quiet keeps a failure to the command's one line."""
    deadline = time.monotonic() + timeout
    for t in threading.enumerate():
        if t not in before and type(t).__module__.startswith("orbax") and t is not threading.current_thread():
            t.join(max(0.0, deadline - time.monotonic()))


@contextlib.contextmanager
def _quiet_absl() -> Iterator[None]:
    """Keep library noise off stderr while orbax runs.

    orbax logs expected failures (and a line per save) at ERROR/INFO through absl; and a failed
    read of a damaged checkpoint makes tensorstore print "Event loop is closed" tracebacks later
    (see :func:`_run_drained`, swapped in for orbax's loop runner while this context is active).
    When the body fails, the threads it started are given time to finish before the loggers speak
    again (:func:`_join_new_threads`).
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
        _join_new_threads(before, _SETTLE_S)
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


def _key_name(k: Any) -> str:
    tu = jax.tree_util
    if isinstance(k, tu.GetAttrKey):
        s = k.name
    elif isinstance(k, tu.DictKey):
        s = str(k.key)
    elif isinstance(k, tu.SequenceKey):
        s = str(k.idx)
    elif isinstance(k, tu.FlattenedIndexKey):
        s = str(k.key)
    else:  # pragma: no cover - future key types
        s = str(k)
    return re.sub(r"[^A-Za-z0-9_]", "_", s)


def _flatten(tree: Any) -> tuple[list[str], list[Any], Any]:
    """(names, leaves, treedef) with names from the key paths; names are unique."""
    with_path, treedef = jax.tree_util.tree_flatten_with_path(tree)
    names = [_SEP.join(_key_name(k) for k in path) for path, _ in with_path]
    if len(set(names)) != len(names):  # pragma: no cover - a naming bug, not a user error
        raise AssertionError("leaf names of the training state are not unique")
    return names, [leaf for _, leaf in with_path], treedef


def _layout(names: list[str], leaves: list[Any]) -> dict[str, list]:
    return {n: [list(map(int, x.shape)), str(np.dtype(x.dtype))] for n, x in zip(names, leaves)}


def _digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _sha256_file(path: pathlib.Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


@functools.lru_cache(maxsize=1)
def _git_commit() -> str | None:
    """The checkout's commit (one ``git rev-parse`` per process, not one per save)."""
    root = pathlib.Path(nmrl.__file__).resolve().parents[1]
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                             timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def _versions() -> dict[str, str | None]:
    return dict(_versions_once())


@functools.lru_cache(maxsize=1)
def _versions_once() -> dict[str, str | None]:
    from importlib import metadata as im

    out: dict[str, str | None] = {"nmrl": nmrl.__version__, "python": platform.python_version()}
    for dist in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "orbax-checkpoint", "numpy"):
        try:
            out[dist] = im.version(dist)
        except im.PackageNotFoundError:
            out[dist] = None
    return out


def _fsync_tree(path: pathlib.Path) -> None:
    """Flush the files and directories of a finished checkpoint (and its parent entry) to disk."""
    for root, _dirs, files in os.walk(path):
        for f in files:
            store.fsync_path(os.path.join(root, f))
        store.fsync_path(root)
    store.fsync_path(path.parent)


def _learner_of_meta(meta: dict) -> "learners.Learner":
    """The learner a checkpoint's or compact state's metadata names (none: the actor-critic)."""
    try:
        return learners.get(meta.get(learners.KEY) or learners.DEFAULT)
    except ValueError as e:
        raise CheckpointError(f"{meta.get('path', '?')}: {e}") from e


def _as_state_trees(path: Any, config: Config, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` ({field: nested dict by leaf name}, as read back) in the structure the learner's state
    gives those fields (its NamedTuples and dataclasses, e.g. observation statistics), read from
    ``jax.eval_shape`` of its ``init`` (nothing is computed); a field whose leaf names differ from the
    learner's raises CorruptCheckpoint."""
    learner = learners.of(config)
    template = jax.eval_shape(learner.make(config).init, jax.random.PRNGKey(0))
    out = {}
    for f, tree in params.items():
        names, _, treedef = _flatten(getattr(template, f))
        have_names, have, _ = _flatten(tree)
        got = dict(zip(have_names, have))
        if sorted(got) != sorted(names):
            raise CorruptCheckpoint(f"{path}: the saved {f} does not fit the learner {learner.name!r}'s state")
        out[f] = jax.tree_util.tree_unflatten(treedef, [got[n] for n in names])
    return out


def _nest(flat: dict[str, Any], heads: tuple[str, ...]) -> dict[str, Any]:
    """``{head: tree}`` from flat names ``head.a.b`` (a name equal to ``head`` is a bare array)."""
    tree: dict = {}
    for name, x in flat.items():
        head, _, rest = name.partition(_SEP)
        if head not in heads:
            continue
        if not rest:
            tree[head] = x
            continue
        node = tree.setdefault(head, {})
        *parents, leaf = rest.split(_SEP)
        for k in parents:
            node = node.setdefault(k, {})
        node[leaf] = x
    return tree


def _abstract(tree: Any) -> Any:
    sharding = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    return jax.tree.map(lambda s: jax.ShapeDtypeStruct(s.shape, s.dtype, sharding=sharding), tree)


def _err(path: pathlib.Path, what: str, exc: BaseException | None = None,
         cls: type[CheckpointError] = CheckpointError) -> CheckpointError:
    """A one-line error naming ``path`` (and the first line of ``exc``, cut to 300 characters)."""
    msg = f"{path}: {what}"
    if exc is not None:
        detail = str(exc).strip().splitlines()
        msg += f" ({type(exc).__name__}: {detail[0][:300] if detail else ''})"
    return cls(msg)


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


def _to_device(x: np.ndarray) -> jax.Array:
    return jax.device_put(x, jax.local_devices()[0])


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
