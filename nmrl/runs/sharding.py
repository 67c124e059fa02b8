"""Split a batch of environments over the local (CPU) devices.

On a CPU machine XLA runs one vmapped MJX program on essentially one thread; with
``XLA_FLAGS=--xla_force_host_platform_device_count=N`` (set before JAX starts) and the batch split
with ``jax.shard_map`` each device runs its shard on its own thread. Measured on the 2-core
reference machine (results/benchmarks/env.json, docs/performance.md): batch 256, 4 solver iterations,
42-46k physics steps/s on 2 devices vs 15-23k on 1; GSPMD (``jit`` with sharded inputs) ~= 1
device (26k); ``pmap`` slower (9.5k).

A known problem is recorded in docs/performance.md (a 2-device run of the bare environment at
batch 4096 hung; the benchmarks run their workers under a timeout).

Usage::

    mesh = make_mesh()                                   # 1-D mesh "b" over jax.local_devices()
    states = shard_batch(jax.vmap(env.reset)(keys), mesh)
    rollout = shard_map_batch(lambda s, k: my_vmapped_rollout(s, k), mesh)   # jit-ed
    states, keys, ret = rollout(states, shard_batch(akeys, mesh))  # same sharding in and out

Why ``shard_batch`` and not ``jax.device_put(tree, NamedSharding(mesh, P("b")))``: MJX's Data has
zero-size leaves (``act``, ``mocap_pos``, ...; shape (B, 0)) that come back from a sharded
computation *replicated*; if they went in sharded, the second call sees new input shardings and
recompiles (tens of seconds on 2 cores) -- which looked like a "30x slower" 2-device run.
``shard_batch`` replicates zero-size and 0-d leaves up front, so every call hits the cache.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

AXIS = "b"


def make_mesh(devices=None) -> Mesh:
    """A 1-D mesh with axis ``"b"`` over ``devices`` (default: all local devices)."""
    devs = jax.local_devices() if devices is None else list(devices)
    return Mesh(np.array(devs), (AXIS,))


def process_devices(per_process: int | None = None) -> list:
    """The first ``per_process`` devices of every process (default: all), in process order.

    In a 1-process run these are the local devices; in a multi-process run (nmrl/runs/distributed.py)
    the mesh over them spans every process, each contributing the same number of devices.
    """
    out = []
    for p in range(jax.process_count()):
        mine = sorted((d for d in jax.devices() if d.process_index == p), key=lambda d: d.id)
        out += mine if per_process is None else mine[:per_process]
    return out


def put(tree: Any, shardings: Any) -> Any:
    """``jax.device_put(tree, shardings)``, also where the shardings span several processes.

    Across processes every process passes the same (host or local) values; each keeps the shards
    of its own devices (``jax.make_array_from_callback``). An array already laid out as asked is
    passed through.
    """
    if jax.process_count() == 1:
        return jax.device_put(tree, shardings)

    def one(x, s):
        if isinstance(x, jax.Array) and x.sharding == s:
            return x
        h = np.asarray(x)
        return jax.make_array_from_callback(h.shape, s, lambda idx: h[idx])

    return jax.tree.map(one, tree, shardings)


def _sharding(x, mesh: Mesh) -> NamedSharding:
    shape = np.shape(x)
    if len(shape) == 0 or int(np.prod(shape)) == 0:
        return NamedSharding(mesh, P())
    if shape[0] % mesh.size:
        raise ValueError(f"batch size {shape[0]} is not divisible by the {mesh.size} devices")
    return NamedSharding(mesh, P(AXIS))


def shard_batch(tree: Any, mesh: Mesh | None = None) -> Any:
    """Place a batched pytree (leading axis = batch) split over ``mesh``; zero-size leaves replicated."""
    mesh = make_mesh() if mesh is None else mesh
    return put(tree, jax.tree.map(lambda x: _sharding(x, mesh), tree))


def shard_map_batch(f: Callable, mesh: Mesh | None = None, jit: bool = True) -> Callable:
    """``jax.shard_map`` of a batch-polymorphic ``f`` over the leading axis of every argument/output."""
    mesh = make_mesh() if mesh is None else mesh
    g = jax.shard_map(f, mesh=mesh, in_specs=P(AXIS), out_specs=P(AXIS), check_vma=False)
    return jax.jit(g) if jit else g


def train_state_specs(ts: Any, env_fields: Sequence[str] = ("slots",)) -> Any:
    """PartitionSpecs for a learner's state: its per-environment fields (``env_fields``; the
    actor-critic's ``slots``) split over ``"b"``, everything else (parameters, optimizer states, key,
    hyperparameters, counters) replicated."""
    def spec(path, _x):
        return P(AXIS) if getattr(path[0], "name", None) in env_fields else P()

    return jax.tree_util.tree_map_with_path(spec, ts)


def shard_train_chunk(chunk: Callable, ts: Any, mesh: Mesh, env_fields: Sequence[str] = ("slots",)
                      ) -> tuple[Callable, Callable]:
    """(program, place): ``chunk`` (built with ``make(..., axis_name=AXIS, num_shards=mesh.size)``)
    under ``shard_map`` over the environment axis of ``env_fields``, and a function that lays a state
    out as the program expects (call it on the initial state and on every returned state)."""
    specs = train_state_specs(ts, env_fields)
    shardings = jax.tree.map(lambda s: NamedSharding(mesh, s), specs)
    program = jax.shard_map(chunk, mesh=mesh, in_specs=(specs,), out_specs=(specs, P()), check_vma=False)

    def place(t: Any) -> Any:
        return put(t, shardings)

    return program, place
