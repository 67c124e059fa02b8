"""Per-second invariants of nmrl.experiments.timescale (the finer-delta study's conversion rules)."""

import math

import numpy as np
import pytest

from nmrl.paper import likelihood
from nmrl.learners.ac_config import TrainConfig
from nmrl.experiments.timescale import at_control_step

BASE = TrainConfig()  # the paper's constants at 0.02 s


@pytest.mark.parametrize("dt", [0.02, 0.01, 0.005])
def test_per_second_quantities_are_unchanged(dt):
    c = at_control_step(BASE, dt, 0.2)
    steps_per_s = 1 / dt
    assert math.isclose(c.gamma ** steps_per_s, BASE.gamma ** 50, rel_tol=1e-9)
    assert math.isclose(c.alpha ** steps_per_s, BASE.alpha ** 50, rel_tol=1e-9)
    assert math.isclose(dt / c.environment.stop_prob, 5.0, rel_tol=1e-9)  # mean trial length [s]
    # a constant reward rate r gives the same discounted return (an integral over time) at every dt
    r = 1.7
    ret = sum(c.gamma ** t * c.reward_scale * r for t in range(int(round(30 / dt))))
    ret0 = sum(BASE.gamma ** t * r for t in range(int(round(30 / 0.02))))
    assert math.isclose(ret, ret0, rel_tol=0.02)
    assert c.l == round(0.2 / dt) and c.lam == BASE.lam
    # the same number of sampled actions per period as at 0.02 s with l = 10, Delta = 4
    assert len(likelihood.sampled_indices(c.l, c.delta)) == len(likelihood.sampled_indices(10, 4))
    # ... at the same instants in seconds
    np.testing.assert_allclose(likelihood.sampled_indices(c.l, c.delta) * dt, likelihood.sampled_indices(10, 4) * 0.02)


def test_stationary_arm_decays_traces_per_second():
    c = at_control_step(BASE, 0.005, None)
    assert c.l == 1
    assert math.isclose(c.lam ** 200, BASE.lam ** 50, rel_tol=1e-9)


def test_bad_values():
    with pytest.raises(ValueError, match="control_dt"):
        at_control_step(BASE, 0.0, 0.2)
    with pytest.raises(ValueError, match="period_seconds"):
        at_control_step(BASE, 0.02, -1.0)
    with pytest.raises(ValueError, match="not a positive integer"):
        at_control_step(BASE, 0.02, 0.03)
