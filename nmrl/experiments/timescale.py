"""The same learning problem at another control step delta (the finer-delta study's scaling).

The paper runs one control step, delta_0 = 0.02 s. To compare delta in {0.02, 0.01, 0.005} s on
the same problem in continuous time, every per-step constant is converted so that its meaning per
second is unchanged (k = delta / delta_0):

* discount per second:           gamma_delta = gamma_0 ** k            (gamma^{1/delta} fixed)
* noise correlation per second:  alpha_delta = alpha_0 ** k            (alpha^{1/delta} fixed, eq. (4))
* mean trial length in seconds:  stop_prob_delta = stop_prob_0 * k     (5 s at the paper's 1/250)
* nm-period of a fixed duration: l_delta = period_seconds / delta; the stationary arm keeps l = 1
* sampled actions per period:    Delta_delta = Delta_0 / k (the same instants are sampled)
* trace decay per second:        lambda is applied once per period (Table II); an arm whose period
                                 has a fixed duration keeps lambda_0, the stationary arm (period =
                                 delta) uses lambda_0 ** k
* rewards per second: (8)-(14) are rates (m/s, and penalties that are functions of the state at
  the step's end), so the learner receives r_t * k (``reward_scale``): the discounted sum
  sum_t gamma^t r_t k approximates the same integral over time at every delta and V keeps its
  scale. The average reward per second, sum of the received rewards over a second, is then
  mean(r_t) / delta_0, directly comparable across delta.
Step sizes are not converted: they are chosen per arm by a grid (the study's rule).

:class:`TimescaleSpec` is the study's design: the control steps, the arms (the stationary policy
and nm-periods of fixed durations), the step-size grid and the budgets in simulated seconds, and
every run's config made from the paper's constants by :func:`at_control_step`. Each of its fields
is declared once with ``option(...)`` (the control steps and the physics as the runs' own
environment fields, nmrl.tasks.EnvFields), so ``nmrl study``'s options and the checks are made from
the declarations. It is stored as the study's ``study.json`` (:meth:`TimescaleSpec.to_json`).

On a Gymnasium task (``env``, docs/tasks.md) the trial's end and the reward's scale are the task's
own: it ends by its own rule and time limit (the stop probability stays the default it refuses to
change), and its rewards already are rates integrated over the control step (r_t = r_gym delta /
dt0), so ``reward_scale`` is not converted; the average reward per second is mean(r_t) / delta.
"""

from __future__ import annotations

import argparse
import dataclasses
import math

from nmrl import learners, options, tasks
from nmrl.learners.ac_config import TrainConfig
from nmrl.options import AT_LEAST_ONE, Range, option
from nmrl.paper.control_step import DELTA_0
from nmrl.tasks import EnvFields


def _as_int(x: float, what: str) -> int:
    n = round(x)
    if n < 1 or abs(x - n) > 1e-6:
        raise ValueError(f"{what} = {x:g} is not a positive integer; choose compatible values")
    return n


def at_control_step(base: TrainConfig, control_dt: float, period_seconds: float | None) -> TrainConfig:
    """``base`` (written for delta_0 = 0.02 s) converted to ``control_dt`` by the rules above.

    ``period_seconds`` is the nm-period duration, or None for the stationary policy (l = 1).
    """
    if not control_dt > 0:
        raise ValueError(f"control_dt must be > 0 s, got {control_dt!r}")
    if period_seconds is not None and not period_seconds > 0:
        raise ValueError(f"period_seconds must be > 0 s or None (stationary), got {period_seconds!r}")
    k = control_dt / DELTA_0
    if period_seconds is None:
        l, lam = 1, base.lam ** k
    else:
        l, lam = _as_int(period_seconds / control_dt, "period_seconds / control_dt"), base.lam
    delta = _as_int(base.delta / k, "Delta_0 * delta_0 / control_dt") if k < 1 else max(1, math.floor(base.delta / k))
    paper = base.environment.env == tasks.PAPER  # a task keeps its own end of a trial and its rates (above)
    stop_prob = base.environment.stop_prob
    cfg = options.replace(
        base, control_dt=control_dt, l=l, lam=lam, delta=delta,
        gamma=base.gamma ** k, alpha=base.alpha ** k, stop_prob=stop_prob * k if paper else stop_prob,
        reward_scale=base.reward_scale * k if paper else base.reward_scale,
    )
    cfg.validate()
    return cfg


def arm_name(period: float | None) -> str:
    return "stationary" if period is None else f"p{period:g}s"


def period(text: str) -> float | None:
    """A period on the command line: seconds, or ``stationary`` (also ``none``, ``1``: l = 1) as None."""
    if text in ("stationary", "none", "1"):
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"period {text!r} is invalid: give seconds > 0 or 'stationary'") from None


_SECONDS = Range(0.0, open_lo=True, why="simulated seconds")
_STEP_SIZE = Range(0.0, open_lo=True, why="a step size")


@dataclasses.dataclass(frozen=True)
class TimescaleSpec:
    """The study's design, each field declared once (nmrl/options.py: help, range, command-line
    spelling; ``nmrl study``'s options are made from the declarations, :meth:`validate` checks by them
    and then what relates the fields)."""

    dts: tuple[float, ...] = options.same_as(EnvFields, "control_dt", (0.02, 0.01, 0.005), flag="dt",
                                             help="control steps [s]", group=None)
    #: None = the stationary policy
    periods: tuple[float | None, ...] = option((None, 0.1, 0.2, 0.4), "nm-period durations [s]; 'stationary' = l = 1",
                                               range=Range(0.0, open_lo=True, why="seconds, or stationary"),
                                               parse=period)
    beta_theta_grid: tuple[float, ...] = option((3e-6, 1e-5, 3e-5), "the grid's actor step sizes beta^theta",
                                                flag="beta-theta", range=_STEP_SIZE)
    beta_v_grid: tuple[float, ...] = option((5e-5, 1.5e-4, 5e-4), "the grid's critic step sizes beta^v", flag="beta-v",
                                            range=_STEP_SIZE)
    grid_seconds: float = option(40.0, "simulated seconds per environment in a grid run", range=_SECONDS)
    final_seconds: float = option(150.0, "simulated seconds per environment in a final run", range=_SECONDS)
    chunk_seconds: float = option(5.0, "simulated seconds per jitted chunk", range=_SECONDS)
    seeds: int = option(3, "seeds of each arm's final runs", range=AT_LEAST_ONE)
    num_envs: int = option(32, "environments in lock-step", range=AT_LEAST_ONE)
    checkpoint_every: int = option(3, "chunks between checkpoints", range=AT_LEAST_ONE)
    gradvar_envs: int = option(64, "environments of the gradient-variance measurement", range=AT_LEAST_ONE)
    gradvar_batches: int = option(8, "batches of the gradient-variance measurement",
                                  range=Range(2, why="need >= 2 batches for an interval"))
    #: the paper's constants at delta_0 = 0.02 s
    base: TrainConfig = option(TrainConfig(), "the paper's constants at delta_0 = 0.02 s", cli=False)
    #: if set, the rule chooses only among grid pairs with beta^theta <= this (the same for every arm)
    beta_theta_cap: float | None = option(None, "choose only among grid pairs with beta_theta <= this (every arm)",
                                          range=_STEP_SIZE)
    #: every run's physics engine (declared and checked as the runs' own: nmrl.tasks.EnvFields)
    physics: str = options.same_as(EnvFields, "physics", "mjx", group=None)

    def validate(self) -> None:
        """Every field by its declaration (nmrl/options.py), then what relates them: distinct control
        steps and periods, a cap within the grid, budgets of whole chunks, chunks of whole control steps,
        every arm's config at every control step (a period of whole steps, the environment's rules)."""
        def bad(name, allowed):
            return options.invalid(name, getattr(self, name), allowed)

        options.check(self, limits=False)
        if len(set(self.dts)) != len(self.dts):
            raise bad("dts", "each control step may appear once")
        if len(set(self.periods)) != len(self.periods):
            raise bad("periods", "each period may appear once")
        if self.beta_theta_cap is not None and self.beta_theta_cap < min(self.beta_theta_grid):
            raise bad("beta_theta_cap", f"must be >= the smallest grid value {min(self.beta_theta_grid):g}")
        for name in ("grid_seconds", "final_seconds"):
            if abs(getattr(self, name) / self.chunk_seconds - round(getattr(self, name) / self.chunk_seconds)) > 1e-9:
                raise bad(name, f"must be a multiple of chunk_seconds={self.chunk_seconds:g}")
        for dt in self.dts:
            self._steps(self.chunk_seconds, dt, "chunk_seconds")
            for p in self.periods:
                learners.get("ac").validate(self.arm_config(dt, p))  # raises if period / dt is not an integer, an unknown env, ...

    @staticmethod
    def _steps(seconds: float, dt: float, what: str) -> int:
        n = round(seconds / dt)
        if n < 1 or abs(seconds / dt - n) > 1e-6:
            raise ValueError(f"{what}={seconds:g} s is not a whole number of control steps of {dt:g} s")
        return n

    def arm_config(self, dt: float, period: float | None) -> TrainConfig:
        cfg = at_control_step(self.base, dt, period)
        return options.replace(cfg, num_envs=self.num_envs, physics=self.physics,
                                   chunk_steps=self._steps(self.chunk_seconds, dt, "chunk_seconds"))

    def grid_points(self, dt: float) -> tuple[list[str], list[TrainConfig]]:
        names, cfgs = [], []
        steps = self._steps(self.grid_seconds, dt, "grid_seconds")
        for p in self.periods:
            for bt in self.beta_theta_grid:
                for bv in self.beta_v_grid:
                    names.append(f"{arm_name(p)}_bt{bt:.1e}_bv{bv:.1e}")
                    cfgs.append(options.replace(self.arm_config(dt, p), beta_theta=bt, beta_v=bv,
                                                    steps=steps, seed=0))
        return names, cfgs

    def final_points(self, dt: float, chosen: dict[str, tuple[float, float]]) -> tuple[list[str], list[TrainConfig]]:
        names, cfgs = [], []
        steps = self._steps(self.final_seconds, dt, "final_seconds")
        for p in self.periods:
            bt, bv = chosen[arm_name(p)]
            for s in range(self.seeds):
                names.append(f"{arm_name(p)}_s{s}")
                cfgs.append(options.replace(self.arm_config(dt, p), beta_theta=bt, beta_v=bv,
                                                steps=steps, seed=s))
        return names, cfgs

    def to_json(self) -> dict:
        d = {**dataclasses.asdict(self), "base": options.flat(self.base)}  # the learner's config flat, as config.json
        d["dts"], d["periods"] = list(self.dts), list(self.periods)
        d["beta_theta_grid"], d["beta_v_grid"] = list(self.beta_theta_grid), list(self.beta_v_grid)
        return d

    @staticmethod
    def from_json(d: dict) -> "TimescaleSpec":
        d = dict(d)
        for k in ("dts", "periods", "beta_theta_grid", "beta_v_grid"):
            d[k] = tuple(d[k])
        d["base"] = options.build(TrainConfig, **d["base"])
        return TimescaleSpec(**d)
