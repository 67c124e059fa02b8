"""Checkpoints of a training run (orbax-checkpoint), and the one import of every checkpoint function.

The full checkpoints live here; the files they are made of in nmrl/runs/checkpoint_files.py, orbax's
step directories that hold them in nmrl/runs/checkpoint_steps.py, the run identity in
nmrl/runs/identity.py, the compact continuation states in nmrl/runs/compact.py and other learners'
trees in nmrl/runs/trees.py; their public names are importable from this module.

One :class:`Checkpointer` per run holds one orbax ``CheckpointManager`` for a whole session (the
chunk loop, nmrl/runs/loop.py, opens one per point): its ``save(ts, config)`` (or the one-off
``save(run_dir, ts, config)``) writes the whole state of any learner (nmrl/learners/contract.py; for
the actor-critic the :class:`~nmrl.learners.ac_train.TrainState`: theta, v, every
:class:`~nmrl.learners.ac_train.EnvSlot` with its MJX state, noise, likelihood ratio and traces, the PRNG key,
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

Checkpoints of the layout without optimizer states (the update written by hand, not through
optax) have the same schema but their state lacks the optimizer states ``opt_theta.*`` and ``opt_v.*``. ``restore`` accepts such a
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
"""

from __future__ import annotations

import json
import os
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import nmrl
from nmrl import learners, options
from nmrl.paper.env import MODEL_PATH
from nmrl.runs import io_errors, store
from nmrl.runs.store import CHECKPOINTS, COMPACT_FILE
from nmrl.runs.checkpoint_files import (FORMAT, SCHEMA_VERSION, Config, Params, State, Trainer, _SEP, _abstract,
                                        _digest, _err, _flatten, _fsync_tree, _git_commit, _layout, _learner_of_meta,
                                        _nest, _as_state_trees, _sha256_file, _to_device, _versions)
from nmrl.runs.checkpoint_steps import *  # noqa: F401,F403  (the public names of each part, see __all__)
from nmrl.runs.checkpoint_steps import _manager, _ocp, _quiet_absl, _restore_items, checkpoint_dir, load_metadata
from nmrl.runs.compact import *  # noqa: F401,F403
from nmrl.runs.compact import restore_compact_params, uses_compact
from nmrl.runs.errors import CheckpointError, CorruptCheckpoint, ForeignCheckpoint
from nmrl.runs.identity import *  # noqa: F401,F403
from nmrl.runs.identity import _check_config, _check_model, _config_from_meta, identity_digest
from nmrl.runs.trees import *  # noqa: F401,F403

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


def _policy_template(meta: dict) -> dict[str, Params]:
    """Shapes of the saved policy parameters (the learner's ``policy_fields``), read from the
    checkpoint's own layout: nothing here assumes an environment's dimensions."""
    heads = _learner_of_meta(meta).policy_fields
    tree = _nest({n: jax.ShapeDtypeStruct(tuple(shape), np.dtype(dtype))
                  for n, (shape, dtype) in meta["state_layout"].items()}, heads)
    if set(tree) != set(heads):
        raise CorruptCheckpoint(f"{meta['path']}: the saved layout has no policy parameters ({', '.join(heads)})")
    return tree


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
            "config": options.flat(config),
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
        except Exception as e:  # noqa: BLE001
            io_errors.remove_partial_saves(d)  # orbax's unfinished <step>.orbax-checkpoint-tmp*
            f = io_errors.find(e, d / str(step))
            if f is not None:  # the disk or file system: one line naming the path and the cause
                raise io_errors.IOFailure(f, hint="the checkpoints saved before are intact; continue with --resume "
                                                  "once the cause is gone") from None
            if isinstance(e, CheckpointError):
                raise
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
    return meta, config, _as_state_trees(path, config, {h: to_dev(restored[h]) for h in heads})


if __name__ == "__main__":  # pragma: no cover - `python -m nmrl.runs.checkpoint RUN` prints the metadata
    m = load_metadata(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else None)
    m.pop("state_layout", None)
    print(json.dumps(m, indent=2))
