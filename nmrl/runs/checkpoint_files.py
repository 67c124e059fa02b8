"""The files of checkpoints: flat named arrays, their layout and digests, and provenance.

Shared by the full checkpoints (nmrl/runs/checkpoint.py), the run identity (nmrl/runs/identity.py),
the compact continuation states (nmrl/runs/compact.py) and other learners' trees
(nmrl/runs/trees.py): a pytree is saved as a flat dict of arrays named by its key paths
(``slots.env.data.qpos``), with its layout (shape, dtype per name) and a sha256 digest of the bytes,
so that the format does not depend on the Python classes of the pytree and a restore detects
silently corrupted data; provenance (library versions, the checkout's commit, the model file's
sha256) is looked up once per process. orbax's step directories that hold these files are
nmrl/runs/checkpoint_steps.py's. Every failure a caller can meet raises :class:`CheckpointError`
naming the path (:class:`CorruptCheckpoint`: unreadable or not matching its digest;
:class:`ForeignCheckpoint`: of another run; nmrl/runs/errors.py).
"""

from __future__ import annotations

import functools
import hashlib
import os
import pathlib
import platform
import re
import subprocess
from typing import Any

import jax
import numpy as np

import nmrl
from nmrl import learners
from nmrl.runs import store
from nmrl.runs.errors import CheckpointError, CorruptCheckpoint

__all__ = ['SCHEMA_VERSION']

#: Version of the on-disk layout of a checkpoint; bump when it changes incompatibly.
SCHEMA_VERSION = 1
FORMAT = "nmrl-checkpoint"
ITEMS = ("state", "policy", "meta")

_SEP = "."
Params = Any
#: A learner's state; its config and trainer are the contract's Protocols (nmrl/learners/contract.py).
Config = learners.Config
State = Any
Trainer = learners.Trainer


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


def _to_device(x: np.ndarray) -> jax.Array:
    return jax.device_put(x, jax.local_devices()[0])
