"""Checkpoints of any pytree (another learner's state, e.g. the Brax PPO baseline's parameters and
observation normalizer), in the run store's layout: orbax step directories and a compact npz."""

from __future__ import annotations

import json
import os
import pathlib
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nmrl.runs import store
from nmrl.runs.checkpoint_files import (SCHEMA_VERSION, _abstract, _digest, _err, _flatten, _fsync_tree, _git_commit,
                                        _layout, _to_device, _versions)
from nmrl.runs.checkpoint_steps import _manager, _ocp, _quiet_absl, _resolve_step, _restore_items, checkpoint_dir
from nmrl.runs.compact import _read_npz, compact_path
from nmrl.runs.errors import CheckpointError, CorruptCheckpoint

__all__ = ['TREE_FORMAT', 'save_tree', 'restore_tree', 'save_tree_compact', 'restore_tree_compact']


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
