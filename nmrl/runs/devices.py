"""How many XLA host (CPU) devices a command uses; decided before JAX is imported.

On a CPU, XLA runs one program on one device, and one device keeps essentially one core busy;
``--xla_force_host_platform_device_count=K`` (an ``XLA_FLAGS`` entry read once, when JAX starts)
exposes K host devices so that K shards run side by side. ``nmrl train`` and ``nmrl sweep`` call
:func:`configure` first thing, so they use every core by default without the user setting
``XLA_FLAGS``; ``--devices 1`` (or ``NMRL_DEVICES=1``) turns it off, ``--devices K`` asks for K.
The flag only concerns the host platform: on a GPU/TPU machine the accelerators are used as usual.

K devices in one process share XLA's CPU thread pool, which has one thread per core by default.
Each device's program runs on one of its threads, and some operations hand sub-tasks to the same
pool and block until they finish: jaxlib's batched LAPACK kernels (``ParallelBatchMap``, e.g. the
Cholesky of MJX's Newton solver once a batch holds about 820 of the robot's 9 x 9 matrices) and
the hand-over of a large operand to a ``pure_callback`` (the C physics). When K is at least the
pool's size, all its threads can block at once and the program waits for ever. :func:`configure`
therefore sizes the pool to K + 1 threads (``PJRT_NPROC``, read once by XLA's CPU client) whenever
K >= the pool's default; a spare thread costs nothing while idle, and the pool's size does not
change any result (checked bit for bit on the actor-critic and PPO on both physics).
A ``PJRT_NPROC`` or ``NPROC`` the user set is kept.

This module must not import JAX.
"""

from __future__ import annotations

import os
import re
import sys

FLAG = "--xla_force_host_platform_device_count"
AUTO = "auto"


def cpu_cores() -> int:
    """Cores this process may run on (its CPU affinity, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def parse(value: str | int | None) -> int | None:
    """``'auto'``/None -> None (every core), an integer >= 1 -> itself; anything else: ValueError."""
    if value is None or value == AUTO:
        return None
    try:
        n = int(value)
    except (TypeError, ValueError):
        n = 0
    if n < 1 or str(value).strip() != str(n):
        raise ValueError(f"--devices={value!r} is invalid: give 'auto' (every core) or an integer >= 1")
    return n


def requested(argv: list[str]) -> str | None:
    """The value of ``--devices`` in ``argv`` (``--devices K`` or ``--devices=K``), else NMRL_DEVICES."""
    for i, a in enumerate(argv):
        if a == "--devices" and i + 1 < len(argv):
            return argv[i + 1]
        if a.startswith("--devices="):
            return a.split("=", 1)[1]
    return os.environ.get("NMRL_DEVICES")


def configure(value: str | int | None) -> int:
    """Set the host device count in ``XLA_FLAGS`` (before JAX starts); returns the count asked for.

    Too late when JAX is already imported (e.g. ``cli.main`` called from a test): then nothing is
    changed and the command uses the devices that exist. An explicit count replaces a count already
    in ``XLA_FLAGS``; ``auto`` keeps one the user set.
    """
    n = parse(value)
    flags = os.environ.get("XLA_FLAGS", "")
    has = re.search(FLAG + r"=(\d+)", flags)
    if "jax" in sys.modules:
        return n if n is not None else int(has.group(1)) if has else cpu_cores()
    if n is None and has:
        n = int(has.group(1))
    else:
        n = cpu_cores() if n is None else n
        flags = re.sub(FLAG + r"=\d+", "", flags).strip()
        if n > 1:
            flags = f"{flags} {FLAG}={n}".strip()
        os.environ["XLA_FLAGS"] = flags
    pool = pool_threads(n)
    if pool is not None:
        os.environ["PJRT_NPROC"] = str(pool)
    return n


def pool_threads(devices: int) -> int | None:
    """The CPU thread pool's size that ``devices`` host devices need (see the module docstring):
    ``devices + 1`` when the default pool (one thread per core) is not larger than ``devices``;
    None when the default suffices or the user sized the pool (``PJRT_NPROC`` or ``NPROC``)."""
    if devices < 2 or "PJRT_NPROC" in os.environ or "NPROC" in os.environ:
        return None
    return devices + 1 if cpu_cores() <= devices else None
