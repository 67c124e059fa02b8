"""Bounds that mean something for every number of a learner's config, checked before anything runs.

A learner computes in float32 and counts in int32: a value that Python holds exactly may not
survive the cast (``--sigma 1e300`` becomes inf, the noise NaN, and the run "diverges" in its first
chunk; ``--control-dt 1e300`` makes an environment that steps 2e302 physics steps). So every field
of a config (any learner, nmrl/learners/contract.py) is checked by its type and its declaration
(nmrl/options.py, where each field's range is declared once with the field):

* ``float``: finite once rounded to float32 (``|x| <~ 3.40e38``) and, when not 0, not below
  float32's smallest normal number (``1.18e-38``; it would become 0 or lose its precision);
* ``int``: within int32 (``< 2**31``), as the step and trial counters and the traced integers are,
  unless the field's range says otherwise (the seed: 32-bit unsigned, nmrl.options.SEED_MAX);
* the range or choices the field declares (e.g. the control step at most 1 s, a stop probability in
  [0, 1], a noise standard deviation in (0, 10], step sizes in [0, 1]).

Each refusal is one line ``NAME=VALUE is invalid: ...`` naming what is allowed.
"""

from __future__ import annotations

from typing import Any

from nmrl import options


def check_value(name: str, value: Any, kind: type = float) -> None:
    """ValueError (one line) unless ``value`` is representable for its use: float32 for ``float``,
    int32 for ``int``. None passes."""
    options.check_value(name, value, kind)


def check(config: Any, skip: frozenset[str] = frozenset()) -> None:
    """Every field of the dataclass ``config`` (but ``skip``) by its type and declaration, in field
    order: ValueError for the first that is out of bounds (:func:`nmrl.options.check`)."""
    options.check(config, skip)

