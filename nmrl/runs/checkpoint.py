"""Checkpoints of a training run (orbax-checkpoint).

One :class:`Checkpointer` per run holds one orbax ``CheckpointManager`` for a whole session (the
driver, nmrl/runs/driver.py, opens one per point): its ``save(ts, config)`` (or the one-off
``save(run_dir, ts, config)``) writes the whole state of any learner (nmrl/learners/contract.py; for
the actor-critic the :class:`~nmrl.paper.learner.TrainState`: theta, v, every
:class:`~nmrl.paper.learner.EnvSlot` with its MJX state, noise, likelihood ratio and traces, the PRNG key,
the traced hyperparameters, the counters and the divergence flag) to ``RUN_DIR/checkpoints/<step>/``;
``restore(run_dir, trainer)`` gives it back bit for bit, so a resumed run continues exactly as an
uninterrupted one. ``restore_policy`` reads only the learner's policy parameters (the
actor-critic's theta, v) for evaluation.

On disk one checkpoint is an orbax step directory with three items::

    RUN_DIR/checkpoints/<step>/
        state/    every non-empty leaf of the state, as a flat dict name -> array
        policy/   the learner's policy_fields again, e.g. {"theta": ..., "v": ...} (small; evaluation
                  reads only this)
        meta/     JSON: schema, learner, config, versions, git commit, model sha256, layout, digests, extra
        _CHECKPOINT_METADATA, commit_success.txt   (orbax's own)

Why a flat dict: orbax cannot save zero-size arrays (MJX keeps a few, e.g. ``data.act`` of shape
(N, 0)), and flat names make the format independent of the Python classes of the pytree. Empty
leaves are rebuilt from the template on restore. The flat names are the pytree key paths
(``slots.env.data.qpos``); the layout (shape, dtype per name) and a sha256 digest of the array
bytes are stored in the metadata, so a restore checks structure before reading and detects
silently corrupted data after reading.

Atomicity: orbax writes the step into ``<step>.orbax-checkpoint-tmp*`` and renames it to ``<step>``
when complete (local file systems); unfinished tmp directories are ignored by readers. ``save`` is
synchronous (async checkpointing off) and fsyncs the files before returning. The checkout's git
commit and the library versions recorded in the metadata are looked up once per process.

Checkpoints written before the update went through optax (issue 16) have the same schema but
their state lacks the optimizer states ``opt_theta.*`` and ``opt_v.*``. ``restore`` accepts such a
checkpoint when nothing else is missing or different and gives it fresh optimizer states
(``trainer.init_opt`` of the restored theta, v and hyperparameters). That is exact: those runs used
the paper's rule theta += beta^theta sum_e d_e z_e (Table II), now ``optax.sgd`` under
``optax.inject_hyperparams``, whose state is only a count that sgd never reads and the step size,
which the learner takes from the restored ``Hyper`` at every step anyway; and their config (which
the restore checks against the trainer) can only name that rule. A resumed old run continues bit
for bit as it would have (tests/test_checkpoint.py, tests/data/schema1_sgd_run/).

Every failure a caller can meet (missing run, no checkpoints, unknown step, corrupted or truncated
files, another model, an incompatible config) raises :class:`CheckpointError` naming the path; a
checkpoint that cannot be read (or does not match its digest) raises the subclass
:class:`CorruptCheckpoint` (an older checkpoint may still be good: :func:`newest_good`), one of
another run (config or model) the subclass :class:`ForeignCheckpoint`.

Identity. A run directory has one identity: the config it was created with (``config.json``,
every field but the budget ``steps``/``trials``) and the model file's sha256. Every checkpoint
records its config and model hash (and, from this version on, their digest ``identity``;
checkpoints without it are checked through their config and model hash alone);
:func:`check_identity` refuses a checkpoint whose identity differs from its run's, naming both.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import hashlib
import json
import logging
import os
import pathlib
import platform
import re
import subprocess
import sys
import time
from typing import Any, Iterator

import jax
import jax.numpy as jnp
import numpy as np

import nmrl
from nmrl import learners
from nmrl.paper.env import MODEL_PATH
from nmrl.runs import store
from nmrl.runs.store import CHECKPOINTS, COMPACT_FILE

__all__ = [
    "CheckpointError",
    "Checkpointer",
    "save",
    "latest_step",
    "all_steps",
    "load_metadata",
    "load_config",
    "restore",
    "restore_policy",
    "restore_params",
    "restore_compact_params",
    "checkpoint_dir",
    "SCHEMA_VERSION",
    "save_compact",
    "load_compact",
    "restore_compact",
    "has_compact",
    "uses_compact",
    "save_compact_policy",
    "restore_compact_policy",
    "CorruptCheckpoint",
    "ForeignCheckpoint",
    "RUN_CONFIG",
    "load_run_config",
    "identity_config",
    "identity_digest",
    "check_identity",
    "newest_good",
    "save_tree",
    "restore_tree",
    "save_tree_compact",
    "restore_tree_compact",
]

#: Version of the on-disk layout below; bump when it changes incompatibly.
SCHEMA_VERSION = 1
FORMAT = "nmrl-checkpoint"
ITEMS = ("state", "policy", "meta")
#: Config fields that may differ between a checkpoint and the trainer that resumes it (the budget);
#: every other field is part of the run's identity.
RESUMABLE_FIELDS = ("steps", "trials")
#: The run's config, written when the run is created (nmrl/runs/store.py); the reference of its identity.
RUN_CONFIG = store.CONFIG_FILE

_SEP = "."
Params = Any
#: A learner's config (nmrl/learners/contract.py), its state and its Trainer.
Config = Any
State = Any
Trainer = Any


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


@contextlib.contextmanager
def _quiet_absl() -> Iterator[None]:
    """Keep library noise off stderr while orbax runs.

    orbax logs expected failures (and a line per save) at ERROR/INFO through absl; and a failed
    read of a damaged checkpoint makes tensorstore print "Event loop is closed" tracebacks later
    (see :func:`_run_drained`, swapped in for orbax's loop runner while this context is active).
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
    try:
        yield
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


def _policy_template(meta: dict) -> dict[str, Params]:
    """Shapes of the saved policy parameters (the learner's ``policy_fields``), read from the
    checkpoint's own layout: nothing here assumes an environment's dimensions."""
    heads = _learner_of_meta(meta).policy_fields
    tree = _nest({n: jax.ShapeDtypeStruct(tuple(shape), np.dtype(dtype))
                  for n, (shape, dtype) in meta["state_layout"].items()}, heads)
    if set(tree) != set(heads):
        raise CorruptCheckpoint(f"{meta['path']}: the saved layout has no policy parameters ({', '.join(heads)})")
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


# ----------------------------------------------------------------------------- save


class Checkpointer:
    """The checkpoints of one run for one session: one orbax ``CheckpointManager`` opened once.

    ``keep`` newest checkpoints are kept (orbax's ``max_to_keep``); with ``every_steps`` the
    manager's own save policy (``save_interval_steps``: steps that are multiples of it, and the
    first save of a run without checkpoints) answers :meth:`should_save`. Use as a context manager
    or call :meth:`close`.
    """

    def __init__(self, run_dir: str | os.PathLike, *, keep: int = 3, every_steps: int | None = None):
        if not (isinstance(keep, int) and keep >= 1):
            raise ValueError(f"keep must be an integer >= 1, got {keep!r}")
        self.run_dir = pathlib.Path(run_dir)
        self.dir = checkpoint_dir(run_dir)
        self.keep, self.every_steps = keep, every_steps
        self._m = None

    def _manager(self):
        if self._m is None:
            try:
                with _quiet_absl():
                    self._m = _manager(self.dir, keep=self.keep, save_interval_steps=self.every_steps)
            except Exception as e:  # noqa: BLE001
                raise _err(self.dir, "cannot open the checkpoints for writing", e) from e
        return self._m

    def steps(self) -> list[int]:
        return sorted(int(s) for s in self._manager().all_steps())

    def latest_step(self) -> int | None:
        return self._manager().latest_step()

    def should_save(self, step: int) -> bool:
        """Whether the save policy asks for a checkpoint at ``step`` (never for a step <= the newest)."""
        with _quiet_absl():
            return bool(self._manager().should_save(int(step)))

    def save(self, ts: State, config: Config, *, extra: dict | None = None) -> pathlib.Path:
        """Write the full training state at step ``int(ts.step)`` (see :func:`save`)."""
        extra = {} if extra is None else extra
        try:
            json.dumps(extra, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise TypeError(f"extra must be a JSON-serializable dict: {e}") from e
        d = self.dir
        step = int(ts.step)
        names, leaves, _ = _flatten(ts)
        state_host = {n: np.asarray(x) for n, x in zip(names, leaves)}
        layout = _layout(names, list(state_host.values()))
        state_item = {n: a for n, a in state_host.items() if a.size > 0}
        learner = learners.of(config)
        policy_item = {f: jax.tree.map(np.asarray, getattr(ts, f)) for f in learner.policy_fields}
        pnames, pleaves, _ = _flatten(policy_item)
        model_sha = _sha256_file(MODEL_PATH)
        try:
            ident = identity_digest(config, model_sha)
        except (ValueError, TypeError):  # a config that does not resolve: saved as it is, checked on restore
            ident = None

        meta = {
            "format": FORMAT,
            "schema": SCHEMA_VERSION,
            "step": step,
            "trials": int(ts.trials),
            **({"periods": int(ts.periods)} if hasattr(ts, "periods") else {}),
            "diverged": bool(ts.diverged),
            learners.KEY: learner.name,
            "config": dataclasses.asdict(config),
            "versions": _versions(),
            "git_commit": _git_commit(),
            "model_file": str(MODEL_PATH.relative_to(MODEL_PATH.parents[1])),
            "model_sha256": model_sha,
            "identity": ident,
            "saved_unix_time": time.time(),
            "state_layout": layout,
            "state_digest": _digest(state_item),
            "policy_digest": _digest(dict(zip(pnames, pleaves))),
            "extra": extra,
        }
        ocp = _ocp()
        try:
            with _quiet_absl():
                m = self._manager()
                if step in m.all_steps():
                    m.delete(step)
                m.save(
                    step,
                    args=ocp.args.Composite(
                        state=ocp.args.StandardSave(state_item),
                        policy=ocp.args.StandardSave(policy_item),
                        meta=ocp.args.JsonSave(meta),
                    ),
                    force=True,
                )
                m.wait_until_finished()
        except CheckpointError:
            raise
        except Exception as e:  # noqa: BLE001
            raise _err(d / str(step), "saving the checkpoint failed", e) from e
        path = d / str(step)
        if not path.is_dir():
            raise CheckpointError(f"{path}: orbax reported success but the step directory is missing")
        _fsync_tree(path)
        return path

    def close(self) -> None:
        if self._m is not None:
            with _quiet_absl():
                self._m.close()
            self._m = None

    def __enter__(self) -> "Checkpointer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def save(
    run_dir: str | os.PathLike,
    ts: State,
    config: Config,
    *,
    keep: int = 3,
    extra: dict | None = None,
) -> pathlib.Path:
    """Write the full training state at step ``int(ts.step)``; keep the newest ``keep`` checkpoints.

    Returns the step directory. Synchronous and atomic (see the module docstring). Saving a step
    that already exists replaces it. ``extra`` must be JSON-serializable; it is stored in the
    metadata unchanged. (A loop that saves many times holds one :class:`Checkpointer` instead.)
    """
    with Checkpointer(run_dir, keep=keep) as c:
        return c.save(ts, config, extra=extra)


# ----------------------------------------------------------------------------- load


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


def _config_from_meta(meta: dict) -> Config:
    path = meta.get("path", "?")
    cfg = meta["config"]
    cls = _learner_of_meta(meta).config
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(cfg) - known - {learners.KEY})
    if unknown:
        raise CheckpointError(f"{path}: the saved config has fields this nmrl does not know: {unknown}")
    try:
        return cls(**{k: v for k, v in cfg.items() if k != learners.KEY})
    except TypeError as e:
        raise _err(pathlib.Path(path), "the saved config is invalid", e, CorruptCheckpoint) from e


def load_config(run_dir: str | os.PathLike, step: int | None = None) -> Config:
    """The config a checkpoint was saved with (as passed to :func:`save`)."""
    return _config_from_meta(load_metadata(run_dir, step))


def _check_model(meta: dict) -> None:
    now = _sha256_file(MODEL_PATH)
    if meta["model_sha256"] != now:
        raise ForeignCheckpoint(
            f"{meta['path']}: checkpoint of another model: {meta.get('model_file')} had sha256 "
            f"{meta['model_sha256']}, {MODEL_PATH} now has {now}"
        )


def _check_config(meta: dict, config: Config) -> None:
    saved = _config_from_meta(meta)
    if type(saved) is not type(config):
        raise ForeignCheckpoint(f"{meta['path']}: checkpoint of the learner {learners.of(saved).name!r}, the "
                                f"trainer is {learners.of(config).name!r}")
    try:
        a = dataclasses.asdict(saved.resolved())
    except ValueError as e:
        raise _err(pathlib.Path(meta["path"]), "the saved config is invalid", e) from e
    b = dataclasses.asdict(config.resolved())
    diff = [f"{k}: checkpoint {a[k]!r} != trainer {b[k]!r}" for k in a if k not in RESUMABLE_FIELDS
            and a[k] != b[k]]
    if diff:
        raise ForeignCheckpoint(f"{meta['path']}: config incompatible with the trainer: " + "; ".join(diff))


def _to_device(x: np.ndarray) -> jax.Array:
    return jax.device_put(x, jax.local_devices()[0])


def restore(run_dir: str | os.PathLike, trainer: Trainer, step: int | None = None) -> State:
    """Restore the full training state for an exact resume with ``trainer`` (newest step if None).

    Checks the model file's sha256 and the config (every field but the budget) against the
    trainer, the saved layout against ``jax.eval_shape(trainer.init, key)``, and the data digest.
    The arrays come back with the template's shapes and dtypes, committed to the default device.
    A checkpoint that lacks only state fields the learner may fill (its ``restorable``, e.g. the
    actor-critic's optimizer states, see the module docstring) gets them from its ``fill``.
    """
    meta = load_metadata(run_dir, step)
    path = pathlib.Path(meta["path"])
    _check_model(meta)
    _check_config(meta, trainer.config)

    template = jax.eval_shape(trainer.init, jax.random.PRNGKey(0))
    names, tleaves, treedef = _flatten(template)
    want = _layout(names, tleaves)
    have = meta["state_layout"]
    learner = learners.of(trainer.config)
    opt_names = {n for n in want if n.split(_SEP, 1)[0] in learner.restorable}
    migrate = not any(n in have for n in opt_names)  # an old checkpoint: no optimizer state saved
    if migrate:
        want = {n: w for n, w in want.items() if n not in opt_names}
    if want != have:
        missing = sorted(set(want) - set(have))
        unexpected = sorted(set(have) - set(want))
        changed = [f"{n}: saved {have[n]} vs expected {want[n]}" for n in want
                   if n in have and have[n] != want[n]]
        raise CheckpointError(
            f"{path}: the saved training state does not fit this trainer: missing {missing[:5]}, "
            f"unexpected {unexpected[:5]}, changed {changed[:5]}"
        )
    nonempty = {n: t for n, t in zip(names, tleaves) if int(np.prod(t.shape)) > 0 and n in want}
    ocp = _ocp()
    restored = _restore_items(path.parent, int(meta["step"]),
                              state=ocp.args.StandardRestore(_abstract(nonempty))).state
    host = {}
    for n, t in nonempty.items():
        a = restored.get(n) if isinstance(restored, dict) else None
        if a is None:
            raise CorruptCheckpoint(f"{path}: the state item lacks the array {n!r}")
        a = np.asarray(a)
        if a.shape != tuple(t.shape) or a.dtype != np.dtype(t.dtype):
            raise CorruptCheckpoint(f"{path}: array {n!r} has {a.shape} {a.dtype}, expected {t.shape} {t.dtype}")
        host[n] = a
    if _digest(host) != meta["state_digest"]:
        raise CorruptCheckpoint(f"{path}: the state data does not match its digest (corrupted checkpoint)")
    leaves = [
        _to_device(host[n]) if n in host else jax.device_put(jnp.zeros(t.shape, t.dtype), jax.local_devices()[0])
        for n, t in zip(names, tleaves)
    ]
    ts = jax.tree_util.tree_unflatten(treedef, leaves)
    if migrate and opt_names:
        ts = jax.device_put(learner.fill(trainer, ts), jax.local_devices()[0])
    return ts


def restore_policy(
    run_dir: str | os.PathLike, step: int | None = None, *, check_model: bool = True
) -> tuple:
    """``(config, *params)`` of a checkpoint for evaluation, ``params`` the learner's ``policy_fields`` in
    order (the actor-critic: ``(config, theta, v)``); reads only the small ``policy`` item.

    A run directory without checkpoints but with a compact state (``compact.npz``, as published
    under ``results/``) gives that state's policy instead (:func:`restore_compact_policy`; ``step``
    must then be None or the compact state's step). With ``check_model`` (default) a checkpoint
    trained on another model file raises CheckpointError.
    """
    meta, config, params = restore_params(run_dir, step, check_model=check_model)
    return (config, *params.values())


def restore_params(run_dir: str | os.PathLike, step: int | None = None, *, check_model: bool = True
                   ) -> tuple[dict, Config, dict[str, Params]]:
    """``(meta, config, params)`` of a checkpoint (or of the compact state of a run without
    checkpoints) for evaluation: ``params`` = {field: tree} over the learner's ``policy_fields``, the
    argument of its ``Policy.act``; ``meta`` has ``step``, ``trials`` and ``path``."""
    if uses_compact(run_dir):
        meta, config, params = restore_compact_params(run_dir, step, check_model=check_model)
        return meta, config, params
    meta = load_metadata(run_dir, step)
    path = pathlib.Path(meta["path"])
    if check_model:
        _check_model(meta)
    config = _config_from_meta(meta)
    template = _policy_template(meta)
    ocp = _ocp()
    restored = _restore_items(path.parent, int(meta["step"]),
                              policy=ocp.args.StandardRestore(_abstract(template))).policy
    heads = list(template)
    try:
        pnames, pleaves, _ = _flatten({h: restored[h] for h in heads})
        tnames, tleaves, _ = _flatten(template)
    except (KeyError, TypeError) as e:
        raise _err(path, "the policy item has an unexpected structure", e, CorruptCheckpoint) from e
    if pnames != tnames or any(tuple(a.shape) != tuple(t.shape) for a, t in zip(pleaves, tleaves)):
        raise CorruptCheckpoint(f"{path}: the policy item does not fit the saved config's network sizes")
    host = {n: np.asarray(a) for n, a in zip(pnames, pleaves)}
    if _digest(host) != meta["policy_digest"]:
        raise CorruptCheckpoint(f"{path}: the policy data does not match its digest (corrupted checkpoint)")
    to_dev = lambda t: jax.tree.map(_to_device, jax.tree.map(np.asarray, t))  # noqa: E731
    return meta, config, {h: to_dev(restored[h]) for h in heads}


# ----------------------------------------------------------------------------- identity


#: Identity fields added after checkpoints with an identity digest were written, with the value
#: every earlier run had: a field at that value is left out of the identity, so the digests (and
#: identity comparisons) of those runs stay what they were (the optimizer chains of issue 16: every
#: run before them used the paper's rule, plain sgd).
LATER_FIELDS: dict[str, object] = {"actor_opt": "sgd", "critic_opt": "sgd", learners.KEY: learners.DEFAULT}


def identity_config(config: Config) -> dict:
    """The fields of a run's identity: the learner's name and the resolved config without the budget
    (``RESUMABLE_FIELDS``), without a field of :data:`LATER_FIELDS` at the value every run had before
    it existed (the learner: the actor-critic)."""
    d = learners.config_dict(config.resolved())
    return {k: v for k, v in d.items()
            if k not in RESUMABLE_FIELDS and not (k in LATER_FIELDS and v == LATER_FIELDS[k])}


def identity_digest(config: Config, model_sha256: str | None) -> str:
    """sha256 of a run's identity (:func:`identity_config` and the model file's sha256)."""
    text = json.dumps({"config": identity_config(config), "model_sha256": model_sha256}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def load_run_config(run_dir: str | os.PathLike) -> Config | None:
    """The config ``RUN_DIR/config.json`` the run was created with (of the learner it names, the
    actor-critic if it names none); None if the run has none."""
    path = pathlib.Path(run_dir) / RUN_CONFIG
    if not path.is_file():
        return None
    try:
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise _err(path, "cannot read the run's config", e) from e
    if not isinstance(d, dict):
        raise CheckpointError(f"{path}: not a run config")
    try:
        cls = learners.get(d.get(learners.KEY) or learners.DEFAULT).config
    except ValueError as e:
        raise CheckpointError(f"{path}: {e}") from e
    known = {f.name for f in dataclasses.fields(cls)} | {learners.KEY}
    if set(d) - known:
        raise CheckpointError(f"{path}: not a run config (unknown fields {sorted(set(d) - known)})")
    try:
        cfg = cls(**{k: v for k, v in d.items() if k != learners.KEY})
        cfg.resolved()
    except (TypeError, ValueError) as e:
        raise _err(path, "the run's config is invalid", e) from e
    return cfg


def check_identity(meta: dict, run_config: Config | None, source: str = "the run's config") -> None:
    """Refuse a checkpoint (``meta`` from :func:`load_metadata`) that is not of the run ``run_config``.

    The checkpoint's own config and model hash must agree with its recorded ``identity`` (when it
    has one: older checkpoints do not) -- else :class:`CorruptCheckpoint`; its model hash must be
    the model file's now, and every identity field of its config must equal ``run_config``'s (the
    run's ``config.json``, named ``source`` in the message) -- else :class:`ForeignCheckpoint`
    naming the fields with both values. ``run_config`` None checks the checkpoint alone.
    """
    path = pathlib.Path(meta["path"])
    saved = _config_from_meta(meta)
    try:
        mine = identity_config(saved)
        digest = identity_digest(saved, meta["model_sha256"])
    except (ValueError, TypeError) as e:
        raise _err(path, "the saved config is invalid", e, CorruptCheckpoint) from e
    recorded = meta.get("identity")
    if recorded is not None and recorded != digest:
        raise CorruptCheckpoint(f"{path}: the metadata's identity {str(recorded)[:16]}... does not match its "
                                f"own config and model hash (edited or corrupted metadata)")
    if run_config is not None:
        theirs = identity_config(run_config)
        diff = [f"{k}={mine.get(k, LATER_FIELDS.get(k))!r} in the checkpoint but "
                f"{theirs.get(k, LATER_FIELDS.get(k))!r} in {source}"
                for k in sorted(set(theirs) | set(mine)) if mine.get(k) != theirs.get(k)]
        if diff:
            raise ForeignCheckpoint(f"{path}: checkpoint of another run: " + "; ".join(diff))
    _check_model(meta)


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


if __name__ == "__main__":  # pragma: no cover - `python -m nmrl.runs.checkpoint RUN` prints the metadata
    m = load_metadata(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else None)
    m.pop("state_layout", None)
    print(json.dumps(m, indent=2))


# ------------------------------------------------------------------ compact continuation state

COMPACT_FORMAT = "nmrl-compact"
COMPACT_SCHEMA = 1
#: ``kind`` of a compact file that holds a policy for evaluation only (:func:`save_compact_policy`).
POLICY_ONLY = "policy"


def compact_path(run_dir: str | os.PathLike) -> pathlib.Path:
    return pathlib.Path(run_dir) / COMPACT_FILE


def has_compact(run_dir: str | os.PathLike) -> bool:
    return compact_path(run_dir).is_file()


#: state fields every compact continuation state holds besides the learner's ``compact_fields``
COMPACT_COUNTERS = ("step", "trials", "diverged")


def _field_arrays(parts: dict[str, Any]) -> dict[str, np.ndarray]:
    """``{field.leaf_name: array}`` of top-level state fields ``{field: tree}`` (a bare array field:
    ``{field: array}``)."""
    arrays = {}
    for part, tree in parts.items():
        names, leaves, _ = _flatten(tree)
        arrays.update({(f"{part}{_SEP}{n}" if n else part): np.asarray(x) for n, x in zip(names, leaves)})
    return arrays


def save_compact(run_dir: str | os.PathLike, ts: State, config: Config) -> pathlib.Path:
    """Write the compact continuation state of a run: the learner's ``compact_fields`` (the
    actor-critic: actor and critic parameters and the count of learned periods), the counters and
    the PRNG key.

    About 42 kB for the actor-critic at the paper's network sizes (no traces, no environment or
    noise state): small enough to commit for every point of a sweep, so that a sweep can continue on
    a fresh clone (:func:`restore_compact`). Written atomically (a temporary file renamed into place).
    """
    learner = learners.of(config)
    arrays = _field_arrays({f: getattr(ts, f) for f in tuple(learner.compact_fields) + COMPACT_COUNTERS})
    arrays["key"] = np.asarray(jax.random.key_data(ts.key) if jnp.issubdtype(ts.key.dtype, jax.dtypes.prng_key)
                               else ts.key)
    return _write_compact(run_dir, arrays, config, {})


def _write_compact(run_dir: str | os.PathLike, arrays: dict[str, np.ndarray], config: Config,
                   extra: dict) -> pathlib.Path:
    """``arrays`` and their metadata (learner, config, model hash, versions, digest, ``extra``) as one
    npz, written atomically into ``run_dir`` (created if missing)."""
    meta = {"format": COMPACT_FORMAT, "schema": COMPACT_SCHEMA, **extra, learners.KEY: learners.of(config).name,
            "config": dataclasses.asdict(config), "model_sha256": _sha256_file(MODEL_PATH), "versions": _versions(),
            "digest": _digest(arrays)}
    arrays = {**arrays, "meta": np.frombuffer(json.dumps(meta).encode(), np.uint8)}
    path = compact_path(run_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    with store.atomic_path(path) as tmp:
        np.savez(tmp, **arrays)
    return path


def save_compact_policy(run_dir: str | os.PathLike, config: Config, *params: Params, step: int,
                        trials: int) -> pathlib.Path:
    """Write a policy (the learner's ``policy_fields``, in order: the actor-critic's theta and v; the
    step and trial counters) in the compact format, for evaluation only: it has no PRNG key, so
    :func:`restore_compact` refuses to continue from it.

    This is how ``results/`` publishes a policy whose full training state is not kept (e.g. one
    copied out of an orbax checkpoint's ``policy`` item). Written atomically.
    """
    fields = learners.of(config).policy_fields
    if len(params) != len(fields):
        raise TypeError(f"save_compact_policy needs {len(fields)} parameter trees ({', '.join(fields)}), "
                        f"got {len(params)}")
    arrays = _field_arrays(dict(zip(fields, params)))
    arrays["step"] = np.asarray(step, np.int32)
    arrays["trials"] = np.asarray(trials, np.int32)
    return _write_compact(run_dir, arrays, config, {"kind": POLICY_ONLY})


def _read_npz(path: pathlib.Path, missing: str) -> tuple[dict, dict[str, np.ndarray]]:
    """(metadata, arrays) of a compact npz (its ``meta`` entry is JSON bytes); CheckpointError
    ``missing`` if there is no file, or naming the file when it cannot be read."""
    if not path.is_file():
        raise CheckpointError(f"{path}: {missing}")
    try:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(arrays.pop("meta").tobytes().decode())
    except Exception as e:  # noqa: BLE001
        raise _err(path, "cannot read the compact state (truncated or corrupted?)", e) from e
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path}: the compact state's metadata is not an object")
    return meta, arrays


def load_compact(run_dir: str | os.PathLike) -> tuple[dict, dict[str, np.ndarray]]:
    """(metadata, arrays) of a compact state; CheckpointError if missing, corrupted or foreign."""
    path = compact_path(run_dir)
    meta, arrays = _read_npz(path, "no compact continuation state")
    if meta.get("format") != COMPACT_FORMAT or meta.get("schema") != COMPACT_SCHEMA:
        raise CheckpointError(f"{path}: not an nmrl compact state of schema {COMPACT_SCHEMA}")
    if _digest(arrays) != meta.get("digest"):
        raise CheckpointError(f"{path}: the compact state does not match its digest (corrupted)")
    meta["path"] = str(path)
    return meta, arrays


def restore_compact(run_dir: str | os.PathLike, trainer: Trainer) -> State:
    """Continue a run from its compact state: the saved ``compact_fields``, counters and key; every
    environment starts a new trial (the actor-critic: reset state, traces z, y = 0, a new nm-period),
    as at any trial start. Statistically, not bitwise, equal to resuming from the full checkpoint.

    The new environment states are drawn from the saved key: ``k_init, key = split(saved key)``,
    ``ts = trainer.init(k_init)`` with the saved fields, the counters and ``key`` replaced. State the
    learner does not keep there starts fresh (the actor-critic's optimizer states: for the paper's
    sgd rule that loses nothing, its state holds no statistics; see the module docstring).
    """
    meta, arrays = load_compact(run_dir)
    if meta.get("kind") == POLICY_ONLY:
        raise CheckpointError(f"{meta['path']}: holds a published policy for evaluation only (no PRNG key), "
                              f"not a continuation state; training cannot continue from it")
    _check_model(meta)
    _check_config(meta, trainer.config)
    learner = learners.of(trainer.config)
    key = jnp.asarray(arrays["key"])
    k_init, key = jax.random.split(key)
    ts = trainer.init(k_init)
    parts = {}
    for part in tuple(learner.compact_fields) + COMPACT_COUNTERS:
        names, leaves, treedef = _flatten(getattr(ts, part))
        keys = [f"{part}{_SEP}{n}" if n else part for n in names]
        try:
            got = [arrays[k] for k in keys]
        except KeyError as e:
            raise CheckpointError(f"{meta['path']}: the compact state lacks {e.args[0]!r}") from e
        out = []
        for k, a, t in zip(keys, got, leaves):
            if part in COMPACT_COUNTERS and a.shape == ():  # counters: the state's own dtype
                a = a.astype(np.dtype(t.dtype))
            if a.shape != tuple(t.shape) or a.dtype != np.dtype(t.dtype):
                raise CheckpointError(f"{meta['path']}: {k} has {a.shape} {a.dtype}, expected "
                                      f"{tuple(t.shape)} {t.dtype}")
            out.append(jnp.asarray(a))
        parts[part] = jax.tree_util.tree_unflatten(treedef, out)
    return learners.replace_state(ts, key=key, **parts)


def uses_compact(run_dir: str | os.PathLike) -> bool:
    """Whether evaluating ``run_dir`` reads its compact state: it has one and no checkpoints directory
    (a published policy; a run with checkpoints is always read from them)."""
    run = pathlib.Path(run_dir)
    return has_compact(run) and not checkpoint_dir(run).exists()


def restore_compact_params(run_dir: str | os.PathLike, step: int | None = None, *, check_model: bool = True
                           ) -> tuple[dict, Config, dict[str, Params]]:
    """``(meta, config, params)`` of a run's compact state, for evaluation (no trainer, no MJX):
    ``params`` = {field: tree} over the learner's ``policy_fields``.

    ``meta`` is the compact state's metadata with ``step`` and ``trials`` (the saved counters) and
    ``path``. The parameter trees are rebuilt from the saved names; their shapes are checked against
    the saved config's networks by the caller's use (a rollout applies them). CheckpointError if
    ``step`` is given and is not the saved step, if the state is corrupted, or (``check_model``)
    trained on another model file.
    """
    meta, arrays = load_compact(run_dir)
    saved = int(arrays["step"])
    if step is not None and int(step) != saved:
        raise CheckpointError(f"{meta['path']}: the compact state is at step {saved}, not {int(step)} "
                              f"(a compact state holds one step only)")
    if check_model:
        _check_model(meta)
    config = _config_from_meta(meta)
    heads = _learner_of_meta(meta).policy_fields
    params = _nest({n: _to_device(a) for n, a in arrays.items()}, heads)
    if set(params) != set(heads):
        raise CorruptCheckpoint(f"{meta['path']}: the compact state has no policy parameters ({', '.join(heads)})")
    meta.update(step=saved, trials=int(arrays["trials"]))
    return meta, config, {h: params[h] for h in heads}


def restore_compact_policy(run_dir: str | os.PathLike, step: int | None = None, *, check_model: bool = True
                           ) -> tuple:
    """``(meta, config, *params)`` of a run's compact state (:func:`restore_compact_params`), the
    learner's ``policy_fields`` in order (the actor-critic: ``(meta, config, theta, v)``)."""
    meta, config, params = restore_compact_params(run_dir, step, check_model=check_model)
    return (meta, config, *params.values())


# ----------------------------------------------------------- checkpoints of other learners' trees

TREE_FORMAT = "nmrl-tree"


def _tree_record(step: int, tree: Any, meta: dict) -> tuple[dict[str, np.ndarray], dict]:
    """(host arrays by leaf name, full metadata) of a tree to save: ``meta`` with the format, step,
    layout, data digest, versions and commit; TypeError if ``meta`` is not JSON."""
    names, leaves, _ = _flatten(tree)
    host = {n: np.asarray(x) for n, x in zip(names, leaves)}
    full = {"format": TREE_FORMAT, "schema": SCHEMA_VERSION, "step": int(step), **meta,
            "layout": _layout(names, list(host.values())), "digest": _digest(host),
            "versions": _versions(), "git_commit": _git_commit(), "saved_unix_time": time.time()}
    try:
        json.dumps(full, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise TypeError(f"meta must be a JSON-serializable dict: {e}") from e
    return host, full


def save_tree(run_dir: str | os.PathLike, step: int, tree: Any, meta: dict, *, keep: int = 3) -> pathlib.Path:
    """Save any pytree of arrays (another learner's state, e.g. the PPO baseline's parameters and
    observation normalizer) as the orbax checkpoint ``RUN_DIR/checkpoints/STEP``, the run store's
    layout. ``meta`` (JSON) is stored beside it with the tree's layout and data digest; the newest
    ``keep`` checkpoints are kept. Synchronous and atomic, like :func:`save`."""
    host, full = _tree_record(step, tree, meta)
    d = checkpoint_dir(run_dir)
    ocp = _ocp()
    try:
        with _quiet_absl(), _manager(d, keep=keep) as m:
            if int(step) in m.all_steps():
                m.delete(int(step))
            m.save(int(step), args=ocp.args.Composite(state=ocp.args.StandardSave(host),
                                                      meta=ocp.args.JsonSave(full)), force=True)
            m.wait_until_finished()
    except Exception as e:  # noqa: BLE001
        raise _err(d / str(step), "saving the checkpoint failed", e) from e
    path = d / str(step)
    _fsync_tree(path)
    return path


def _tree_template(path: pathlib.Path, meta: Any, template: Any) -> tuple[list[str], list[Any], Any]:
    """(names, leaves, treedef) of ``template`` after checking that the saved tree's ``meta`` is an
    nmrl tree of exactly its layout (names, shapes, dtypes: the differences named in the error)."""
    if not isinstance(meta, dict) or meta.get("format") != TREE_FORMAT:
        raise CheckpointError(f"{path}: not an nmrl tree checkpoint (metadata has no format={TREE_FORMAT!r})")
    names, tleaves, treedef = _flatten(template)
    tleaves = [x if hasattr(x, "dtype") else jnp.asarray(x) for x in tleaves]  # Python scalars: JAX's dtype
    want = _layout(names, tleaves)
    if meta.get("layout") != want:
        have = meta.get("layout") or {}
        diff = sorted(set(want) ^ set(have)) + [n for n in want if n in have and want[n] != have[n]]
        raise CheckpointError(f"{path}: the saved tree does not fit this learner's: {diff[:5]}")
    return names, tleaves, treedef


def restore_tree(run_dir: str | os.PathLike, template: Any, step: int | None = None) -> tuple[dict, Any]:
    """``(meta, tree)`` of a :func:`save_tree` checkpoint (the newest if ``step`` is None), the tree
    with ``template``'s structure; CheckpointError if it is not such a checkpoint, does not fit the
    template (names, shapes, dtypes: named in the message) or fails its digest."""
    d, step = _resolve_step(run_dir, step)
    path = d / str(step)
    meta = _restore_items(d, step, meta=_ocp().args.JsonRestore()).meta
    names, tleaves, treedef = _tree_template(path, meta, template)
    abstract = {n: jax.ShapeDtypeStruct(tuple(t.shape), np.dtype(t.dtype)) for n, t in zip(names, tleaves)}
    restored = _restore_items(d, step, state=_ocp().args.StandardRestore(_abstract(abstract))).state
    host = {n: np.asarray(restored[n]) for n in names}
    if _digest(host) != meta.get("digest"):
        raise CorruptCheckpoint(f"{path}: the saved tree does not match its digest (corrupted checkpoint)")
    meta["path"] = str(path)
    return meta, jax.tree_util.tree_unflatten(treedef, [_to_device(host[n]) for n in names])


def save_tree_compact(run_dir: str | os.PathLike, step: int, tree: Any, meta: dict) -> pathlib.Path:
    """The same tree and metadata as :func:`save_tree`, as one small npz ``RUN_DIR/compact.npz``
    (replaced atomically at every call): what a run that is continued across machines commits, since
    ``checkpoints/`` is not committed. :func:`restore_tree_compact` reads it back exactly."""
    host, full = _tree_record(step, tree, meta)
    blob = json.dumps(full, allow_nan=False).encode()
    if "meta" in host:
        raise ValueError("a tree leaf may not be named 'meta' (the compact file's metadata entry)")
    path = compact_path(run_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    with store.atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **host, meta=np.frombuffer(blob, np.uint8))
    return path


def restore_tree_compact(run_dir: str | os.PathLike, template: Any, step: int | None = None) -> tuple[dict, Any]:
    """``(meta, tree)`` of a :func:`save_tree_compact` file, checked like :func:`restore_tree`
    (format, layout against ``template``, digest); CheckpointError if ``step`` is given and is not
    the one step the file holds."""
    path = compact_path(run_dir)
    meta, host = _read_npz(path, "no compact state")
    if step is not None and int(step) != meta.get("step"):
        raise CheckpointError(f"{path}: the compact state is at step {meta.get('step')}, not {int(step)} "
                              f"(a compact state holds one step only)")
    names, _, treedef = _tree_template(path, meta, template)
    if _digest({n: host[n] for n in names}) != meta.get("digest"):
        raise CorruptCheckpoint(f"{path}: the compact state does not match its digest (corrupted)")
    meta["path"] = str(path)
    return meta, jax.tree_util.tree_unflatten(treedef, [_to_device(host[n]) for n in names])
