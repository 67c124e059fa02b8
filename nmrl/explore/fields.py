"""The exploration of a run, declared once (nmrl/options.py): which process, and its parameters in
seconds and Hz.

:class:`ExplorationFields` declares each field with ``option(...)``: its help (the kinds that take it,
its unit, range and per-kind default), the values it allows (a :class:`~nmrl.options.Range` or the
kinds), whether it is traced into a learner's noise process, and its option group (:data:`GROUP`).
From the declarations come the command-line options ``--exploration``, ``--period-s``,
``--corr-time-s``, ``--beta``, ``--f-min-hz``, ``--f-max-hz`` and ``--order`` of every learner that
explores (nmrl/cli/exploration_options.py makes them with ``nmrl.runs.parser.add_declared``), the
fields of a config's exploration group (PPO's ``noise``, a subclass of this class), and the check of
each value (``options.check_value`` with the field's declaration: what
:class:`~nmrl.explore.spec.ExplorationSpec` runs on construction, and ``options.check`` on a config).

The module imports no JAX: the declarations are data, read when a command line is built.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from nmrl import options
from nmrl.options import Range, option
from nmrl.paper.control_step import DELTA_0

KINDS = ("white", "nm-periods", "ou", "colored")
DEFAULT_KIND = "nm-periods"  # the paper's process
#: the paper's alpha = 0.8 per 20 ms step as a correlation time
PAPER_CORR_TIME_S = -DELTA_0 / math.log(0.8)
#: each kind's parameters and their defaults (a kind takes exactly the parameters listed here)
DEFAULTS: dict[str, dict[str, Any]] = {
    "white": {},
    "nm-periods": {"period_s": 0.2, "corr_time_s": PAPER_CORR_TIME_S},
    "ou": {"corr_time_s": PAPER_CORR_TIME_S},
    "colored": {"beta": 1.0, "f_min_hz": 0.25, "f_max_hz": 25.0, "order": 6},
}
BETA_RANGE = Range(0.0, 2.0, why="the spectral exponent of 1/f^beta")
ORDER_RANGE = Range(1, 32, why="OU components of the colored fit")
#: a time or a frequency of the process: finite and positive (its relation to the control step is
#: checked by ``ExplorationSpec.validate``)
_SECONDS = Range(0.0, open_lo=True, why="seconds")
_HZ = Range(0.0, open_lo=True, why="Hz")
#: the option group of the exploration's fields on the command line
GROUP = "exploration"
#: the range of a noise standard deviation sigma every learner takes: actions are clipped to [-1, 1]
#: (nmrl/paper/env.py), and at sigma = 10, 92 % of the noise values alone exceed that whole range
SIGMA_RANGE = Range(0.0, 10.0, open_lo=True, why="the exploration noise's standard deviation; actions are "
                                                 "clipped to [-1, 1]", cap=True)



def kinds_of(name: str) -> tuple[str, ...]:
    """The kinds that take the parameter ``name``."""
    return tuple(k for k in KINDS if name in DEFAULTS[k])


def _param(name: str, help: str, unit: str = "", range: Range | None = None) -> Any:
    """The declaration of the parameter ``name``: None (the kind's default), help naming the kinds that
    take it, its unit and their defaults; traced into the learner's noise process (``Hyper.process``)
    but the number of components, a shape of the program."""
    kinds = kinds_of(name)
    unit_ = f" [{unit}]" if unit else ""
    dflt = ", ".join(f"{k}: {DEFAULTS[k][name]:.4g}" for k in kinds)
    return option(None, f"{'/'.join(kinds)} only; {help}{unit_} (default: {dflt})", range=range,
                  traced=name != "order" and "process", group=GROUP)


@dataclasses.dataclass(frozen=True)
class ExplorationFields:
    """The exploration process and its parameters, each declared here once. ``exploration`` None is
    the learner's own default process (a learner that holds these fields gives its default with
    :func:`kind_option`); a parameter None is the kind's default (:data:`DEFAULTS`)."""

    exploration: str | None = option(None, f"the exploration noise process: {', '.join(KINDS)} (docs/exploration.md)",
                                     choices=KINDS, group=GROUP)
    period_s: float | None = _param("period_s", "nm-period duration in seconds, >= the control step; "
                                                "l = round(period_s / control_dt) steps", "s", _SECONDS)
    corr_time_s: float | None = _param("corr_time_s", "correlation time in seconds (> 0, <= 1e4 control steps): "
                                                      "per-step AR coefficient exp(-control_dt / corr_time_s)", "s",
                                       _SECONDS)
    beta: float | None = _param("beta", f"spectral exponent of 1/f^beta in [{BETA_RANGE.lo:g}, {BETA_RANGE.hi:g}] "
                                         "(1 = pink, 0.5 = CN-PPO's best)", range=BETA_RANGE)
    f_min_hz: float | None = _param("f_min_hz", "low end of the power-law band in Hz (0 < f_min_hz < f_max_hz)", "Hz",
                                    _HZ)
    f_max_hz: float | None = _param("f_max_hz", "high end of the power-law band in Hz (<= the Nyquist frequency "
                                                "1 / (2 control_dt))", "Hz", _HZ)
    order: int | None = _param("order", f"number of OU components of the colored fit, an int in "
                                        f"[{int(ORDER_RANGE.lo)}, {int(ORDER_RANGE.hi)}]", range=ORDER_RANGE)


#: the process's parameters (every field but the kind), in field order
PARAMS = tuple(f.name for f in dataclasses.fields(ExplorationFields) if f.name != "exploration")


def kind_option(default: str) -> Any:
    """The field ``exploration`` as :class:`ExplorationFields` declares it, with a learner's default
    process (PPO's: white)."""
    return options.same_as(ExplorationFields, "exploration", default)


def check_field(name: str, value: Any, shown: str | None = None) -> None:
    """ValueError (one line naming the field, or ``shown``, the value and what is allowed) unless the
    declaration of the field ``name`` (``exploration`` for the kind) allows ``value``; None passes."""
    options.check_value(shown or name, value, options.kind(ExplorationFields, name),
                        options.declaration(ExplorationFields, name), limits=False)
