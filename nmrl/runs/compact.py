"""The compact continuation state of a run: ``RUN_DIR/compact.npz``, small enough to commit.

It holds the learner's ``compact_fields`` (nmrl/learners/contract.py; the actor-critic: theta, v and
the count of learned periods), the counters ``step``, ``trials``, ``diverged`` and the PRNG key, with
metadata (learner, config, model sha256, versions) and a digest of the arrays, in one npz written
atomically. A run continues from it statistically, not bitwise, equal (every environment starts a
new trial: :func:`restore_compact`); a policy-only file (:func:`save_compact_policy`) is for
evaluation and cannot be continued.
"""

from __future__ import annotations

import json
import os
import pathlib
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import learners, options
from nmrl.paper.env import MODEL_PATH
from nmrl.runs import store
from nmrl.runs.store import COMPACT_FILE
from nmrl.runs.checkpoint_files import (Config, Params, State, Trainer, _SEP, _as_state_trees, _digest, _err,
                                        _flatten, _learner_of_meta, _nest, _sha256_file, _to_device, _versions)
from nmrl.runs.checkpoint_steps import checkpoint_dir
from nmrl.runs.errors import CheckpointError, CorruptCheckpoint
from nmrl.runs.identity import _check_config, _check_model, _config_from_meta

__all__ = ['COMPACT_FORMAT', 'COMPACT_SCHEMA', 'POLICY_ONLY', 'COMPACT_COUNTERS', 'compact_path', 'has_compact',
           'save_compact', 'load_compact', 'restore_compact', 'uses_compact', 'restore_compact_params',
           'restore_compact_policy', 'save_compact_policy']


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
            "config": options.flat(config), "model_sha256": _sha256_file(MODEL_PATH), "versions": _versions(),
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
    parts = fields_of(meta, arrays, ts, tuple(learner.compact_fields) + COMPACT_COUNTERS)
    return learners.replace_state(ts, key=key, **parts)


def fields_of(meta: dict, arrays: dict[str, np.ndarray], ts: State, fields: tuple[str, ...]) -> dict[str, Any]:
    """The top-level ``fields`` of a compact state's ``arrays`` as trees shaped like ``ts``'s
    (a learner's state of the same config's networks); CheckpointError if one is missing or differs
    in shape or dtype."""
    parts = {}
    for part in fields:
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
    return parts


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
    return meta, config, _as_state_trees(meta["path"], config, {h: params[h] for h in heads})


def restore_compact_policy(run_dir: str | os.PathLike, step: int | None = None, *, check_model: bool = True
                           ) -> tuple:
    """``(meta, config, *params)`` of a run's compact state (:func:`restore_compact_params`), the
    learner's ``policy_fields`` in order (the actor-critic: ``(meta, config, theta, v)``)."""
    meta, config, params = restore_compact_params(run_dir, step, check_model=check_model)
    return (meta, config, *params.values())
