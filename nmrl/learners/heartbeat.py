"""Where a learner's chunk is while it runs: ``beat(stage, i, n)`` inside the jitted chunk tells the
host that step ``i`` of ``n`` of ``stage`` (PPO: ``"rollout"`` unrolls, ``"update"`` epochs) is done.

A chunk is one XLA call; a PPO iteration of the default size runs minutes in it with nothing shown
(nmrl/learners/ppo.py). :func:`beat` is a ``jax.debug.callback`` (kept by XLA for its effect, never
feeding a value back, so the chunk's numbers are the same with or without it) that reaches the
listener :func:`listening` installs (the driver's progress line). It is traced into the program
only while a listener is installed: a host callback's address is part of XLA's persistent-cache key,
so a program with one is compiled afresh by every process (the compile cache, nmrl/cli: ``compile_cache``), and the
driver listens only where the program has host callbacks anyway (MuJoCo C physics). Under
``shard_map`` every shard beats; only shard 0's reach the listener.
"""

from __future__ import annotations

import contextlib
from typing import Callable, Iterator

import jax
import numpy as np

#: the listener ``fn(stage, i, n)`` now, else None
_LISTENER: list[Callable[[str, int, int], None] | None] = [None]


def _host(stage: str, n: int, i, shard) -> None:
    fn = _LISTENER[0]
    if fn is not None and int(np.ravel(shard)[0]) == 0:
        fn(stage, int(np.ravel(i)[0]) + 1, n)


def beat(stage: str, i: jax.Array, n: int, shard: jax.Array | int = 0) -> None:
    """Inside a jitted chunk: step ``i`` (0-based, traced) of ``n`` of ``stage`` is done (``shard``:
    this shard's index under ``shard_map``); nothing is traced while no listener is installed."""
    if _LISTENER[0] is None:
        return
    jax.debug.callback(lambda i_, s_: _host(stage, n, i_, s_), i, jax.numpy.asarray(shard))


@contextlib.contextmanager
def listening(fn: Callable[[str, int, int], None]) -> Iterator[None]:
    """Send the chunk's beats to ``fn(stage, done, n)`` while the block runs."""
    old = _LISTENER[0]
    _LISTENER[0] = fn
    try:
        yield
    finally:
        _LISTENER[0] = old
