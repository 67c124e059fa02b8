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

On a Gymnasium task (``env``, docs/tasks.md) the trial's end and the reward's scale are the task's
own: it ends by its own rule and time limit (the stop probability stays the default it refuses to
change), and its rewards already are rates integrated over the control step (r_t = r_gym delta /
dt0), so ``reward_scale`` is not converted; the average reward per second is mean(r_t) / delta.
"""

from __future__ import annotations

import dataclasses
import math

from nmrl.paper.learner import TrainConfig

#: The paper's control step [s].
DELTA_0 = 0.02


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
    paper = base.env == "paper-cheetah"  # a task keeps its own end of a trial and its rates (above)
    cfg = dataclasses.replace(
        base, control_dt=control_dt, l=l, lam=lam, delta=delta,
        gamma=base.gamma ** k, alpha=base.alpha ** k, stop_prob=base.stop_prob * k if paper else base.stop_prob,
        reward_scale=base.reward_scale * k if paper else base.reward_scale,
    )
    cfg.validate()
    return cfg
