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

Every check raises ValueError naming the bad value and the allowed range; :func:`cli_options` lists
the command-line options (name, type, default, help) so that a CLI can be generated from this file,
and :func:`from_options` builds the spec from their parsed values.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from nmrl.explore.colored import colored_components, time_constants
from nmrl.explore.process import NO_RESET, Process
from nmrl.options import option
from nmrl.paper.control_step import DELTA_0

__all__ = [
    "KINDS",
    "DEFAULT_KIND",
    "DEFAULTS",
    "BETA_RANGE",
    "ORDER_RANGE",
    "MAX_TAU_STEPS",
    "ExplorationSpec",
    "CliOption",
    "cli_options",
    "from_options",
    "config_option",
    "PARAMETERS",
    "corr_time_from_alpha",
    "alpha_from_corr_time",
    "period_steps",
]

KINDS = ("white", "nm-periods", "ou", "colored")
DEFAULT_KIND = "nm-periods"  # the paper's process
#: the paper's alpha = 0.8 per 20 ms step as a correlation time
PAPER_CORR_TIME_S = -DELTA_0 / math.log(0.8)
DEFAULTS: dict[str, dict[str, Any]] = {
    "white": {},
    "nm-periods": {"period_s": 0.2, "corr_time_s": PAPER_CORR_TIME_S},
    "ou": {"corr_time_s": PAPER_CORR_TIME_S},
    "colored": {"beta": 1.0, "f_min_hz": 0.25, "f_max_hz": 25.0, "order": 6},
}
BETA_RANGE = (0.0, 2.0)
ORDER_RANGE = (1, 32)
#: longest time constant in control steps: keeps 1 - phi >= 1e-4, resolved in float32 to < 0.1%
MAX_TAU_STEPS = 1e4
_F32_MAX = float(np.finfo(np.float32).max)
_F32_TINY = float(np.finfo(np.float32).tiny)
_REL = 1e-9  # tolerance of the comparisons against dt (0.2 / 0.02 is not exactly 10)


def _field(help: str, kinds: tuple[str, ...], unit: str = "", type_: type = float) -> Any:
    return dataclasses.field(default=None, metadata={"help": help, "kinds": kinds, "unit": unit, "type": type_})


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
    :meth:`to_dict` / :meth:`from_dict`.
    """

    kind: str = dataclasses.field(metadata={"help": f"exploration process: {', '.join(KINDS)}",
                                            "kinds": KINDS, "unit": "", "type": str})
    sigma: float = dataclasses.field(default=1.0, metadata={
        "help": "marginal standard deviation of the noise xi in every action dimension (> 0, finite in float32)",
        "kinds": KINDS, "unit": "", "type": float})
    period_s: float | None = _field("nm-period duration in seconds, >= the control step; "
                                    "l = round(period_s / control_dt) steps", ("nm-periods",), "s")
    corr_time_s: float | None = _field("correlation time in seconds (> 0, <= 1e4 control steps): "
                                       "per-step AR coefficient exp(-control_dt / corr_time_s)",
                                       ("nm-periods", "ou"), "s")
    beta: float | None = _field(f"spectral exponent of 1/f^beta in [{BETA_RANGE[0]:g}, {BETA_RANGE[1]:g}] "
                                "(1 = pink, 0.5 = CN-PPO's best)", ("colored",))
    f_min_hz: float | None = _field("low end of the power-law band in Hz (0 < f_min_hz < f_max_hz)",
                                    ("colored",), "Hz")
    f_max_hz: float | None = _field("high end of the power-law band in Hz (<= the Nyquist frequency "
                                    "1 / (2 control_dt))", ("colored",), "Hz")
    order: int | None = _field(f"number of OU components of the colored fit, an int in "
                               f"[{ORDER_RANGE[0]}, {ORDER_RANGE[1]}]", ("colored",), "", int)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"exploration kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        own = DEFAULTS[self.kind]
        for f in dataclasses.fields(self):
            if f.name in ("kind", "sigma"):
                continue
            value = getattr(self, f.name)
            if f.name not in own:
                if value is not None:
                    raise ValueError(f"{f.name} is a parameter of {' and '.join(f.metadata['kinds'])}, "
                                     f"not of {self.kind} exploration; got {f.name}={value!r}")
            elif value is None:
                object.__setattr__(self, f.name, own[f.name])
        sigma = _number("sigma", self.sigma)
        if not (math.isfinite(sigma) and _F32_TINY <= sigma <= _F32_MAX):
            raise ValueError(f"sigma must be > 0 and finite in float32 (in [{_F32_TINY:.3g}, {_F32_MAX:.3g}]), "
                             f"got {self.sigma!r}")
        object.__setattr__(self, "sigma", sigma)
        if self.period_s is not None:
            object.__setattr__(self, "period_s", _finite_positive("period_s", self.period_s, " s"))
        if self.corr_time_s is not None:
            object.__setattr__(self, "corr_time_s", _finite_positive("corr_time_s", self.corr_time_s, " s"))
        if self.beta is not None:
            b = _number("beta", self.beta)
            if not (BETA_RANGE[0] <= b <= BETA_RANGE[1]):
                raise ValueError(f"beta must be in [{BETA_RANGE[0]:g}, {BETA_RANGE[1]:g}], got {self.beta!r}")
            object.__setattr__(self, "beta", b)
        if self.f_min_hz is not None:
            lo = _finite_positive("f_min_hz", self.f_min_hz, " Hz")
            hi = _finite_positive("f_max_hz", self.f_max_hz, " Hz")
            if not lo < hi:
                raise ValueError(f"f_min_hz must be < f_max_hz, got f_min_hz={self.f_min_hz!r} and "
                                 f"f_max_hz={self.f_max_hz!r}")
            object.__setattr__(self, "f_min_hz", lo)
            object.__setattr__(self, "f_max_hz", hi)
        if self.order is not None:
            o = self.order
            if isinstance(o, bool | np.bool_) or not isinstance(o, numbers.Integral) \
                    or not ORDER_RANGE[0] <= int(o) <= ORDER_RANGE[1]:
                raise ValueError(f"order must be an int in [{ORDER_RANGE[0]}, {ORDER_RANGE[1]}], got {o!r}")
            object.__setattr__(self, "order", int(o))

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


# ---------------------------------------------------------------------- command line


class CliOption(NamedTuple):
    """One command-line option: ``--<flag>``, parsed into ``dest`` of type ``type`` (default None =
    the kind's default), ``choices`` (or None), ``help`` naming the unit, range and per-kind default."""

    flag: str
    dest: str
    field: str
    type: type
    default: Any
    choices: tuple[str, ...] | None
    help: str


def _help(f: dataclasses.Field) -> str:
    """A parameter's option help: the kinds that take it, its unit, range and per-kind default."""
    m = f.metadata
    dflt = "1.0" if f.name == "sigma" else ", ".join(f"{k}: {DEFAULTS[k][f.name]:.4g}" for k in m["kinds"])
    unit = f" [{m['unit']}]" if m["unit"] else ""
    for_kinds = "" if f.name == "sigma" else f"{'/'.join(m['kinds'])} only; "
    return f"{for_kinds}{m['help']}{unit} (default: {dflt})"


def cli_options() -> tuple[CliOption, ...]:
    """The options of the exploration: ``--exploration`` (the kind) and ``--<parameter>`` for every
    parameter (``--sigma``, ``--period-s``, ``--corr-time-s``, ``--beta``, ``--f-min-hz``,
    ``--f-max-hz``, ``--order``)."""
    opts = []
    for f in dataclasses.fields(ExplorationSpec):
        if f.name == "kind":
            opts.append(CliOption("exploration", "exploration", "kind", str, None, KINDS,
                                  f"{f.metadata['help']} (default: {DEFAULT_KIND}, the paper's eq. (4))"))
            continue
        opts.append(CliOption(f.name.replace("_", "-"), f.name, f.name, f.metadata["type"], None, None, _help(f)))
    return tuple(opts)


def config_option(name: str, default: Any = None) -> Any:
    """The field of a learner's config that holds the spec's ``name`` flat under the same name and
    option (``exploration`` for the kind, ``period_s`` as ``--period-s``, ...; nmrl/options.py):
    the kind's choices, or the parameter's help and None (the kind's default), in the exploration
    option group; a parameter is traced into the learner's noise process (``Hyper.process``)."""
    if name == "exploration":
        return option(default, f"the exploration noise process: {', '.join(KINDS)} (docs/exploration.md)",
                      choices=KINDS, group="exploration")
    static = name == "order"  # the number of components is a shape of the program
    return option(default, _help(ExplorationSpec.__dataclass_fields__[name]), traced=not static and "process",
                  group="exploration")


def from_options(options: Mapping) -> ExplorationSpec:
    """The spec from parsed options keyed by :func:`cli_options` ``dest`` names (e.g. ``vars(args)``;
    other keys are ignored, None means not given): the kind from ``exploration`` (default
    nm-periods), every other parameter from its field name."""
    kw: dict[str, Any] = {}
    for o in cli_options():
        v = options.get(o.dest)
        if v is not None:
            kw[o.field] = v
    kw.setdefault("kind", DEFAULT_KIND)
    return ExplorationSpec(**kw)
