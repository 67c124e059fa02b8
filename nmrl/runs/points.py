"""Many training states as one program: stacking points and laying them out over the devices.

A *point* is one training run (one config, one seed). The points of a sweep or study are of one
learner and differ only in its traced hyperparameters (``hyper_fields``, nmrl/learners/contract.py)
and the seed, so one compiled program runs
all of them (:func:`points_program`, chosen by measurement in benchmarks/bench_sweep.py): MJX's
cost per environment step on a CPU grows with the batch one device holds, so the points are split
over the local devices with ``shard_map`` (no communication; on a CPU nmrl.runs.devices exposes
one device per core) and each device steps its points one after another (``lax.map``; ``group`` > 1
vmaps that many together). A point that is not active (finished, diverged, or waiting for an
earlier stage) is skipped by ``lax.cond``.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P

from nmrl import learners, options
from nmrl.runs import sharding


def stack_trees(trees):
    """Stack pytrees of equal structure along a new leading axis (one entry per point), on the host:
    NumPy arrays, one copy per leaf (``jnp.stack`` of thousands of points' arrays cost a dispatch per
    array: 50 s for 1,000 points); the caller places them (:func:`place_points`, ``jax.device_put``)."""
    return jax.tree.map(lambda *x: np.stack([np.asarray(a) for a in x]), *trees)


def unstack(tree, i: int):
    """Entry ``i`` of a stacked pytree."""
    return jax.tree.map(lambda x: x[i], tree)


def program_key(cfg: Any) -> Any:
    """The part of a config that is compiled into the program (everything but the learner's traced
    hyperparameters and the seed)."""
    return learners.program_key(cfg)


def check_one_program(names: Sequence[str], configs: Sequence[Any]) -> None:
    """ValueError unless every config is of one learner and compiles to the program of the first one."""
    lr = learners.of(configs[0])
    key0 = program_key(configs[0])
    for n, c in zip(names, configs):
        if type(c) is not type(configs[0]):
            raise ValueError(f"point {n!r} is of the learner {learners.of(c).name!r}, {names[0]!r} of {lr.name!r}: "
                             f"one program runs one learner")
        if program_key(c) != key0:
            diff = [k for k, v in options.flat(program_key(c)).items() if v != options.value(key0, k)]
            raise ValueError(f"point {n!r} differs from {names[0]!r} in {diff}: one program can only vary "
                             f"{', '.join(lr.hyper_fields)} and the seed")


def stages(priority, num_points: int) -> list[list[int]]:
    """Stages of point indices: ``None`` = one stage with every point; a list of lists as given
    (points not named form a last stage)."""
    if priority is None:
        return [list(range(num_points))]
    out = [list(st) for st in priority if len(st)]
    named = [i for st in out for i in st]
    if len(set(named)) != len(named) or any(not (0 <= i < num_points) for i in named):
        raise ValueError(f"priority stages {out} must name distinct point indices in range({num_points})")
    rest = [i for i in range(num_points) if i not in set(named)]
    return out + ([rest] if rest else [])


def slot_order(num_points: int, num_devices: int, priority: Sequence[int] | None = None) -> list[int]:
    """Which point sits in which slot of the stacked state (slot j lives on device j // per_device).

    Points are dealt round-robin over the devices in ``priority`` order (default: their own order),
    so every prefix of the priority list (e.g. the paper's named points that run first) is spread
    evenly over the devices. The list is padded with ``-1`` (an idle slot) to a multiple of the devices.
    """
    order = list(range(num_points)) if priority is None else list(priority)
    if sorted(order) != list(range(num_points)):
        raise ValueError(f"priority {order} must be a permutation of range({num_points})")
    per = -(-num_points // num_devices)
    slots = [-1] * (per * num_devices)
    for rank, i in enumerate(order):
        slots[(rank % num_devices) * per + rank // num_devices] = i
    return slots


def points_program(chunk: Callable, num_devices: int, group: int = 1, devices: Sequence | None = None) -> Callable:
    """The points' layout: ``program(ts, active) -> (ts, metrics)`` for stacked point states.

    The points are split over ``num_devices`` devices with ``shard_map`` (no communication at all).
    Within a device the points are stepped one after another by ``lax.map`` (``group`` > 1: in vmapped
    groups of that many), so a device only ever works on one point's environments at a time: MJX's
    cost per environment step on a CPU grows with the batch one device holds (benchmarks/bench_sweep.py).
    A point whose ``active`` flag is False is skipped (``lax.cond``; with ``group`` > 1 it is computed
    and discarded) and comes back unchanged, with zero metrics. ``devices`` (default: the first
    ``num_devices`` local devices) may span several processes (nmrl/runs/distributed.py).
    """
    if not (isinstance(group, int) and not isinstance(group, bool) and group >= 1):
        raise ValueError(f"group={group!r} is invalid: points vmapped together must be an integer >= 1")

    def per_device(ts, active):
        one_ts = jax.tree.map(lambda x: x[0], ts)
        m_shape = jax.eval_shape(chunk, one_ts)[1]

        def one(args):
            t, a = args
            return jax.lax.cond(a, chunk, lambda t: (t, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), m_shape)), t)

        return jax.lax.map(one, (ts, active), batch_size=None if group == 1 else group)

    if num_devices == 1 and devices is None:
        return per_device
    mesh = sharding.make_mesh(jax.local_devices()[:num_devices] if devices is None else devices)
    return jax.shard_map(per_device, mesh=mesh, in_specs=(P(sharding.AXIS), P(sharding.AXIS)),
                         out_specs=P(sharding.AXIS), check_vma=False)


def place_points(tree, num_devices: int, devices: Sequence | None = None):
    """Lay a stacked pytree out as :func:`points_program` expects (its slots over the devices)."""
    if num_devices == 1 and devices is None:
        return jax.device_put(tree, jax.local_devices()[0])
    return sharding.shard_batch(tree, sharding.make_mesh(jax.local_devices()[:num_devices] if devices is None
                                                         else devices))
