"""How many XLA host (CPU) devices a command uses; decided before JAX is imported.

On a CPU, XLA runs one program on one device, and one device keeps essentially one core busy;
``--xla_force_host_platform_device_count=K`` (an ``XLA_FLAGS`` entry read once, when JAX starts)
exposes K host devices so that K shards run side by side. ``nmrl train`` and ``nmrl sweep`` call
:func:`configure` first thing, so they use every core by default without the user setting
``XLA_FLAGS``; ``--devices 1`` (or ``NMRL_DEVICES=1``) turns it off, ``--devices K`` asks for K.
The flag only concerns the host platform: on a GPU/TPU machine the accelerators are used as usual.

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
    if n is None:
        if has:
            return int(has.group(1))
        n = cpu_cores()
    if "jax" in sys.modules:
        return n
    flags = re.sub(FLAG + r"=\d+", "", flags).strip()
    if n > 1:
        flags = f"{flags} {FLAG}={n}".strip()
    os.environ["XLA_FLAGS"] = flags
    return n
