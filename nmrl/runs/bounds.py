"""Bounds that mean something for every number of a learner's config, checked before anything runs.

A learner computes in float32 and counts in int32: a value that Python holds exactly may not
survive the cast (``--sigma 1e300`` becomes inf, the noise NaN, and the run "diverges" in its first
chunk; ``--control-dt 1e300`` makes an environment that steps 2e302 physics steps). So every field
of a config (any learner, nmrl/learners/contract.py) is checked by its type:

* ``float``: finite once rounded to float32 (``|x| <~ 3.40e38``) and, when not 0, not below
  float32's smallest normal number (``1.18e-38``; it would become 0 or lose its precision);
* ``int``: within int32 (``< 2**31``), as the step and trial counters and the traced integers are
  (the seed is checked apart: nmrl/runs/preflight.py, 32-bit unsigned);

and the fields whose meaning is shared by the learners by a range of that meaning (:data:`RANGES`):
the control step at most 1 s (the robot's joints move in tenths of seconds; the physics runs in
steps of the model's 5 ms, nmrl/runs/preflight.py checks the multiple), a stop probability in [0, 1],
a noise standard deviation in (0, 10] (actions are clipped to [-1, 1], nmrl/paper/env.py: at
sigma = 10, 92 % of the noise values alone exceed that whole range in magnitude), step sizes and learning
rates in [0, 1]. Each refusal is one line ``NAME=VALUE is invalid: ...`` naming what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any

import numpy as np

F32_MAX = float(np.finfo(np.float32).max)
F32_TINY = float(np.finfo(np.float32).tiny)
INT32_MAX = 2**31 - 1


@dataclasses.dataclass(frozen=True)
class Range:
    """``lo <= x <= hi`` (``lo`` excluded when ``open_lo``), with the reason in words."""

    lo: float
    hi: float
    open_lo: bool = False
    why: str = ""

    def contains(self, x: float) -> bool:
        return (x > self.lo if self.open_lo else x >= self.lo) and x <= self.hi

    def text(self) -> str:
        return f"{'(' if self.open_lo else '['}{self.lo:g}, {self.hi:g}]"


#: config field -> the range its meaning allows (applied to any learner's config that has the field)
RANGES: dict[str, Range] = {
    "control_dt": Range(0.0, 1.0, open_lo=True, why="seconds per control step, at most 1 s"),
    "stop_prob": Range(0.0, 1.0, why="a probability per control step"),
    "physics_timestep": Range(0.0, 0.1, open_lo=True, why="MuJoCo's timestep in seconds"),
    "trial_s": Range(0.0, 1e6, open_lo=True, why="a mean trial length in seconds"),
    "sigma": Range(0.0, 10.0, open_lo=True,
                   why="the exploration noise's standard deviation; actions are clipped to [-1, 1]"),
    "beta_theta": Range(0.0, 1.0, why="a step size"),
    "beta_v": Range(0.0, 1.0, why="a step size"),
    "learning_rate": Range(0.0, 1.0, why="a step size"),
}


def _kind(cls: type, f: dataclasses.Field) -> type | None:
    """``float`` or ``int`` for a field typed ``float``/``int`` (or ``X | None``), else None."""
    try:
        t = typing.get_type_hints(cls)[f.name]
    except Exception:  # noqa: BLE001 - an unresolvable annotation: not a number field
        return None
    args = [a for a in typing.get_args(t) if a is not type(None)] or [t]
    for k in (float, int):
        if k in args:
            return k
    return None


def check_value(name: str, value: Any, kind: type = float) -> None:
    """ValueError (one line) unless ``value`` is representable for its use: float32 for ``float``,
    int32 for ``int``; then the range of :data:`RANGES`, if ``name`` has one. None passes."""
    if value is None or isinstance(value, bool):
        return
    if kind is int and isinstance(value, int):
        if abs(value) > INT32_MAX:
            raise ValueError(f"{name}={value!r} is invalid: must fit in 32 bits (|{name}| <= {INT32_MAX}), as the "
                             f"counters and traced integers do")
    elif isinstance(value, (int, float)):
        x = float(value)
        with np.errstate(over="ignore", under="ignore"):
            x32 = float(np.float32(x))  # rounded to nearest, as the learner's cast does
        if not math.isfinite(x32):
            raise ValueError(f"{name}={value!r} is invalid: must be a finite number in float32 "
                             f"(|{name}| <= {F32_MAX:.4g}); the learner computes in float32")
        if x != 0 and abs(x32) < F32_TINY:
            raise ValueError(f"{name}={value!r} is invalid: below float32's smallest normal number {F32_TINY:.4g} "
                             f"(it would become 0 or lose its precision); give 0 or a larger value")
    else:
        return
    r = RANGES.get(name)
    if r is not None and not r.contains(float(value)):
        raise ValueError(f"{name}={value!r} is invalid: must be in {r.text()} ({r.why})")


def check(config: Any, skip: frozenset[str] = frozenset({"seed"})) -> None:
    """:func:`check_value` for every ``float``/``int`` field of the dataclass ``config`` (but
    ``skip``), in field order: ValueError for the first that is out of bounds."""
    cls = type(config)
    for f in dataclasses.fields(config):
        if f.name in skip:
            continue
        kind = _kind(cls, f)
        if kind is not None:
            check_value(f.name, getattr(config, f.name), kind)


def control_steps(name: str, dts: Any, example: str) -> None:
    """ValueError (one line) unless ``dts`` is a non-empty list of distinct control steps > 0 s
    (a study's list; ``example`` shows one)."""
    if not dts or any(not (isinstance(d, (int, float)) and not isinstance(d, bool) and d > 0) for d in dts):
        raise ValueError(f"{name}={dts!r} is invalid: give control steps > 0 s, e.g. {example}")
    if len(set(dts)) != len(dts):
        raise ValueError(f"{name}={dts!r} is invalid: each control step may appear once")


def positive_ints(obj: Any, names: typing.Iterable[str]) -> None:
    """ValueError (one line) for the first of ``obj``'s attributes ``names`` that is not an integer >= 1."""
    for name in names:
        v = getattr(obj, name)
        if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
            raise ValueError(f"{name}={v!r} is invalid: must be an integer >= 1")
