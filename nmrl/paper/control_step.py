"""The paper's control step, delta_0 = 0.02 s (Sec. V), and the unit it makes of the rewards.

The paper's rewards are per-step values at delta_0. Runs at another control step delta are put on
the paper's scale through it: a mean reward per step r_t is a reward per second r_t / DELTA_0 at
every delta (the studies' endpoint and tables), and a run at delta scales its rewards by
delta / DELTA_0 (``reward_scale``), so that the discounted return, an integral over time, keeps its
size (nmrl/experiments/timescale.py). It is also the environment's default control step
(nmrl/paper/env.py) and the step at which the paper's alpha = 0.8 holds (nmrl/explore/spec.py).
"""

#: the paper's control step [s]
DELTA_0 = 0.02
#: the paper's probability of stopping a trial after each control step (Sec. V-C: 5 s on average at
#: DELTA_0), the environment's default (nmrl/paper/env.py)
DEFAULT_STOP_PROB = 1 / 250
