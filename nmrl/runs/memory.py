"""A pre-flight estimate of a run's memory: absurd sizes are refused before anything is allocated.

``--num-envs 100000000`` or ``--hidden-actor 1000000000`` make XLA fail to allocate (or the kernel
kill the process) after a long compile, with a traceback of dozens of lines. The training state's
size is known exactly without allocating it: ``jax.eval_shape`` of the learner's ``init``
(nmrl/learners/contract.py; for the actor-critic the per-environment traces are as large as the
networks, so the state grows as N x (M^A + M^C)). What a compiled chunk needs beyond the state was
measured with XLA's own memory analysis (``Compiled.memory_analysis()``; the actor-critic, CPU, one
device, the state donated), with the process's peak resident memory:

    N    M^A   M^C   state      temp (x state)   peak RSS
    8    8     8     0.117 MB   0.062 MB (0.53)  1.27 GiB
    256  8     8     3.67 MB    1.56 MB (0.43)   1.30 GiB
    8    1024  8     2.74 MB    1.11 MB (0.40)   1.31 GiB
    8    8     4096  4.97 MB    1.64 MB (0.33)   1.32 GiB
    64   256   256   7.91 MB    2.42 MB (0.31)   1.35 GiB

So a chunk holds at most 1.53 x the state; a save adds a host copy (1 x), the initial state or a
restore another: :data:`FACTOR` = 4 bounds that with room to spare, :data:`OVERHEAD_BYTES` the
1.3 GiB the process holds at any size (Python, JAX, XLA, MuJoCo, the compiled program).
:func:`preflight` refuses, in one line naming the estimate and the machine's memory, a run whose
estimate exceeds the machine's total memory (it cannot run here at all), and warns when it
exceeds what is available now.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from typing import Any, Callable

import jax
import numpy as np

#: bytes a run holds per byte of training state (the chunk's 1.53 at most, a host copy, a spare state)
FACTOR = 4.0
#: the process's own memory beside the run's arrays (measured 1.27-1.35 GiB peak resident)
OVERHEAD_BYTES = 3 << 29
GIB = float(1 << 30)


class TooLarge(ValueError):
    """The run's estimated memory exceeds the machine's (the message names both); nothing written."""


@dataclasses.dataclass(frozen=True)
class Estimate:
    state_bytes: int  #: the training state of every point (exact, from eval_shape)
    total_bytes: int  #: the estimate for the whole process

    def text(self) -> str:
        return f"about {self.total_bytes / GIB:,.1f} GiB (the training state alone {self.state_bytes / GIB:,.2f} GiB)"


def tree_bytes(tree: Any) -> int:
    """Bytes of the arrays (or ShapeDtypeStructs) of a pytree."""
    return sum(int(np.prod(x.shape, dtype=np.float64)) * np.dtype(x.dtype).itemsize for x in jax.tree.leaves(tree))


def state_bytes(init: Callable, *args: Any) -> int:
    """Bytes of ``init(*args)``'s result, computed from shapes only (nothing allocated)."""
    return tree_bytes(jax.eval_shape(init, *args))


def estimate(init: Callable, *args: Any, points: int = 1) -> Estimate:
    """The memory of a run whose state is ``init(*args)``, ``points`` such states in one program."""
    s = state_bytes(init, *args) * points
    return Estimate(s, int(FACTOR * s) + OVERHEAD_BYTES)


def machine_bytes() -> tuple[int, int]:
    """``(total, available)`` bytes of memory this process may use: /proc/meminfo's MemTotal and
    MemAvailable, lowered to a cgroup's limit (memory.max / memory.limit_in_bytes) when there is one."""
    total = avail = None
    try:
        for line in pathlib.Path("/proc/meminfo").read_text().splitlines():
            k, v = line.split(":", 1)
            if k == "MemTotal":
                total = int(v.split()[0]) * 1024
            elif k == "MemAvailable":
                avail = int(v.split()[0]) * 1024
    except (OSError, ValueError):
        pass
    if total is None:
        try:
            total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError):
            total = 0
    avail = total if avail is None else avail
    for p in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = pathlib.Path(p).read_text().strip()
        except OSError:
            continue
        if text.isdigit() and 0 < int(text) < total:
            total = int(text)
            avail = min(avail, total)
    return total, avail


def preflight(est: Estimate, what: str, warn: Callable[[str], None] | None = None,
              machine: tuple[int, int] | None = None) -> None:
    """Refuse (:class:`TooLarge`) a run whose estimate exceeds the machine's total memory; ``warn``
    when it exceeds the memory available now. ``what`` names the sizes (e.g. ``num_envs=..., hidden_actor=...``)."""
    total, avail = machine_bytes() if machine is None else machine
    if total and est.total_bytes > total:
        raise TooLarge(f"{what} needs {est.text()}, more than this machine's {total / GIB:,.1f} GiB of memory; "
                       f"choose smaller sizes")
    if warn is not None and avail and est.total_bytes > avail:
        warn(f"{what} needs {est.text()}; {avail / GIB:,.1f} GiB of the machine's {total / GIB:,.1f} GiB are "
             f"available now: the run may be killed when memory runs out")
