r"""The exploration setting in physical units: which process, and its parameters in seconds and Hz.

:class:`ExplorationSpec` is the host-side, JSON-serialisable description (plain floats, ints and a
string); :meth:`ExplorationSpec.process` turns it into the traced :class:`~nmrl.explore.process.Process`
for one control step ``dt``. Every parameter with a time meaning is in seconds or Hz, so one spec is
the same physical noise at every control step:

* ``nm-periods``, the paper's eq. (4): within a period ``xi_t = alpha xi_{t-1} + sqrt(1-alpha^2) eps_t``
  with ``alpha = exp(-dt/corr_time_s)``, and a fresh draw every ``l = round(period_s/dt)`` steps
  (the paper's alpha = 0.8, l = 10 at dt = 0.02 s is ``corr_time_s = -0.02/ln 0.8 = 0.0896``,
  ``period_s = 0.2``);
* ``ou``: the same AR(1) without period resets (a sampled Ornstein-Uhlenbeck process);
* ``colored``: a sum of OU components fitted to ``1/f^beta`` over ``[f_min_hz, f_max_hz]``
  (:mod:`nmrl.explore.colored`);
* ``white``: i.i.d. N(0, sigma^2) (the paper's l = 1).

The process and its parameters are declared once, in :class:`nmrl.explore.fields.ExplorationFields`
(help, range, choices; the command line is made from those declarations): a spec checks each value
by its declaration, then what relates them (the parameters its kind takes, the band's ends) and,
given a control step, :meth:`ExplorationSpec.validate`. Every check raises ValueError naming the bad
value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from typing import Any

import jax.numpy as jnp
import numpy as np

from nmrl import options
from nmrl.explore.colored import colored_components, time_constants
from nmrl.explore.fields import (BETA_RANGE, DEFAULT_KIND, DEFAULTS, KINDS, ORDER_RANGE, PAPER_CORR_TIME_S, PARAMS,
                                 check_field, kinds_of)
from nmrl.explore.process import NO_RESET, Process
from nmrl.options import Option, Range

__all__ = [
    "KINDS",
    "DEFAULT_KIND",
    "DEFAULTS",
    "BETA_RANGE",
    "ORDER_RANGE",
    "MAX_TAU_STEPS",
    "ExplorationSpec",
    "PAPER_CORR_TIME_S",
    "PARAMETERS",
    "corr_time_from_alpha",
    "alpha_from_corr_time",
    "period_steps",
]

#: longest time constant in control steps: keeps 1 - phi >= 1e-4, resolved in float32 to < 0.1%
MAX_TAU_STEPS = 1e4
_REL = 1e-9  # tolerance of the comparisons against dt (0.2 / 0.02 is not exactly 10)
#: the noise's standard deviation: positive and, as the process holds it, a normal float32 number
_SIGMA = Option(range=Range(0.0, open_lo=True, why="a standard deviation"))


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    return float(value)


def _finite_positive(name: str, value: Any, unit: str) -> float:
    v = _number(name, value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0{unit}, got {value!r}")
    return v


@dataclasses.dataclass(frozen=True)
class ExplorationSpec:
    """One exploration process, every parameter in physical units (validated on construction).

    Parameters that the kind does not use must be None; those it uses and that are None get the
    kind's default (:data:`DEFAULTS`), so a constructed spec is explicit and round-trips through
    :meth:`to_dict` / :meth:`from_dict`. Each value is checked by its declaration
    (:class:`~nmrl.explore.fields.ExplorationFields`; ``sigma``: > 0 and a normal float32 number).
    """

    kind: str
    sigma: float = 1.0
    period_s: float | None = None
    corr_time_s: float | None = None
    beta: float | None = None
    f_min_hz: float | None = None
    f_max_hz: float | None = None
    order: int | None = None

    def __post_init__(self) -> None:
        if self.kind is None:
            raise options.invalid("kind", None, f"choose one of {', '.join(KINDS)}")
        check_field("exploration", self.kind, shown="kind")
        own = DEFAULTS[self.kind]
        for name in PARAMS:
            value = getattr(self, name)
            if isinstance(value, np.generic):  # a NumPy scalar: its Python number, checked as one
                value = value.item()
            if name not in own:
                if value is not None:
                    raise ValueError(f"{name} is a parameter of {' and '.join(kinds_of(name))}, "
                                     f"not of {self.kind} exploration; got {name}={value!r}")
                continue
            if value is None:
                value = own[name]
            check_field(name, value)
            object.__setattr__(self, name, int(value) if name == "order" else float(value))
        sigma = self.sigma.item() if isinstance(self.sigma, np.generic) else self.sigma
        if sigma is None:
            raise options.invalid("sigma", None, f"must be {_SIGMA.range.text()}")
        options.check_value("sigma", sigma, float, _SIGMA)
        object.__setattr__(self, "sigma", float(sigma))
        if self.f_min_hz is not None and not self.f_min_hz < self.f_max_hz:
            raise ValueError(f"f_min_hz must be < f_max_hz, got f_min_hz={self.f_min_hz!r} and "
                             f"f_max_hz={self.f_max_hz!r}")

    # ------------------------------------------------------------------ control step

    @property
    def num_components(self) -> int:
        """K, the number of latent AR(1) components of the process."""
        return self.order if self.kind == "colored" else 1

    def validate(self, control_dt: float) -> None:
        """Check the spec against a control step (seconds): a period of at least one step, time
        constants of at most :data:`MAX_TAU_STEPS` steps, a band below the Nyquist frequency.

        Raises:
            ValueError: naming the bad value and the allowed range.
        """
        dt = _finite_positive("control_dt", control_dt, " s")
        if self.period_s is not None and self.period_s < dt * (1 - _REL):
            raise ValueError(f"period_s must be >= the control step {dt:g} s, got {self.period_s!r}")
        tau_max = MAX_TAU_STEPS * dt
        if self.corr_time_s is not None and self.corr_time_s > tau_max * (1 + _REL):
            raise ValueError(f"corr_time_s must be in (0, {tau_max:g}] s (at most {MAX_TAU_STEPS:g} control "
                             f"steps of {dt:g} s), got {self.corr_time_s!r}")
        if self.kind == "colored":
            nyquist = 0.5 / dt
            if self.f_max_hz > nyquist * (1 + _REL):
                raise ValueError(f"f_max_hz must be <= the Nyquist frequency {nyquist:g} Hz of the control step "
                                 f"{dt:g} s, got {self.f_max_hz!r}")
            slowest = float(time_constants(self.f_min_hz, self.f_max_hz, self.order)[0])
            if slowest > tau_max * (1 + _REL):
                f_lo = self.f_min_hz * slowest / tau_max
                raise ValueError(f"f_min_hz must be >= {f_lo:.4g} Hz at the control step {dt:g} s (the slowest "
                                 f"component's time constant at most {MAX_TAU_STEPS:g} steps), got {self.f_min_hz!r}")

    def components(self, control_dt: float) -> tuple[np.ndarray, np.ndarray, int]:
        """``(phi (K,), w (K,), period)`` in float64 / int at the control step: the step-domain
        parameters of the state-space family (:mod:`nmrl.explore.process`)."""
        self.validate(control_dt)
        dt = float(control_dt)
        if self.kind == "white":
            return np.zeros(1), np.ones(1), 1
        if self.kind == "colored":
            tau, w = colored_components(self.beta, self.f_min_hz, self.f_max_hz, self.order)
            return np.exp(-dt / tau), w, NO_RESET
        phi = np.array([alpha_from_corr_time(self.corr_time_s, dt)])
        period = period_steps(self.period_s, dt) if self.kind == "nm-periods" else NO_RESET
        return phi, np.ones(1), period

    def process(self, control_dt: float, order: int | None = None) -> Process:
        """The traced :class:`Process` at ``control_dt`` seconds, padded with ``w = 0`` components to
        ``order`` (so that processes of different kinds stack into one vmapped program)."""
        phi, w, period = self.components(control_dt)
        K = len(phi)
        if order is not None:
            if isinstance(order, bool) or not isinstance(order, numbers.Integral) or order < K:
                raise ValueError(f"order (components to pad to) must be an int >= {K} for {self.kind}, "
                                 f"got {order!r}")
            phi = np.concatenate([phi, np.zeros(int(order) - K)])
            w = np.concatenate([w, np.zeros(int(order) - K)])
        return Process(phi=jnp.asarray(phi, jnp.float32), w=jnp.asarray(w, jnp.float32),
                       sigma=jnp.asarray(self.sigma, jnp.float32), period=jnp.asarray(period, jnp.int32))

    # ------------------------------------------------------------------ serialisation

    def to_dict(self) -> dict:
        """The fields as a JSON-serialisable dict (None for the parameters the kind does not use)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping) -> ExplorationSpec:
        """Inverse of :meth:`to_dict`; unknown keys raise ValueError."""
        names = {f.name for f in dataclasses.fields(cls)}
        bad = sorted(set(d) - names)
        if bad:
            raise ValueError(f"unknown exploration parameter(s) {bad}; known: {sorted(names)}")
        if "kind" not in d:
            raise ValueError(f"an exploration spec needs a kind, one of {', '.join(KINDS)}")
        return cls(**dict(d))

    @classmethod
    def from_paper(cls, alpha: float, l: int, control_dt: float, sigma: float = 1.0) -> ExplorationSpec:
        """The paper's (alpha, l) at a control step as an nm-periods spec in seconds."""
        if isinstance(l, bool) or not isinstance(l, numbers.Integral) or l < 1:
            raise ValueError(f"l (nm-period length) must be an int >= 1, got {l!r}")
        return cls("nm-periods", sigma=sigma, period_s=int(l) * float(control_dt),
                   corr_time_s=corr_time_from_alpha(alpha, control_dt))


#: the spec's parameters (every field but the kind), in field order
PARAMETERS = tuple(f.name for f in dataclasses.fields(ExplorationSpec) if f.name != "kind")


# ---------------------------------------------------------------------- conversions


def corr_time_from_alpha(alpha: float, control_dt: float) -> float:
    """The correlation time (s) of a per-step AR coefficient: ``-control_dt / ln(alpha)``."""
    a = _number("alpha", alpha)
    if not 0.0 < a < 1.0:
        raise ValueError(f"alpha must be in the open interval (0, 1) (eq. (4)), got {alpha!r}")
    return -_finite_positive("control_dt", control_dt, " s") / math.log(a)


def alpha_from_corr_time(corr_time_s: float, control_dt: float) -> float:
    """The per-step AR coefficient of a correlation time: ``exp(-control_dt / corr_time_s)``."""
    return math.exp(-_finite_positive("control_dt", control_dt, " s")
                    / _finite_positive("corr_time_s", corr_time_s, " s"))


def period_steps(period_s: float, control_dt: float) -> int:
    """``l = round(period_s / control_dt)`` (halves round up), at least 1."""
    return max(1, int(math.floor(period_s / control_dt + 0.5)))
