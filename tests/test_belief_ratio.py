"""PPO's density at a fragment boundary against the full conditional (nmrl/experiments/belief_ratio.py),
both checked against the Schur complement of the dense covariance of the trial's noise."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from nmrl import options
from nmrl.experiments import belief_ratio
from nmrl.learners import ppo, ppo_config
from nmrl.learners import ppo_networks as nn_
from tests.test_explore import dense_conditional_logpdf, dense_cov
from tests.test_ppo import TINY
from tests.tiny_env import TinyEnv


def test_both_densities_are_the_dense_conditionals_of_their_histories():
    cfg = options.build(ppo_config.PPOConfig, **dict(TINY, exploration="ou", sigma=0.9, corr_time_s=0.1,
                                      learning_rate=3e-2)).resolved()
    env = TinyEnv(stop_prob=0.08)
    tr = ppo.make_ppo(cfg, env)
    st = tr.init(jax.random.PRNGKey(2))
    p = belief_ratio.parts(cfg, st, jax.random.PRNGKey(4), env)
    data = p["data"]
    N, U, T = data.reward.shape

    def xi_std(policy, stats, e):
        mu, std = nn_.mean_std(tr.nets, policy, nn_.normalize(stats, data.obs[e]), cfg.min_std)
        return (np.asarray((data.x[e] - mu) / std, np.float64).reshape(U * T, -1),
                np.asarray(std, np.float64).reshape(U * T, -1))

    proc = st.hyper.process
    checked = 0
    for e in range(N):
        xi_new, std_new = xi_std(p["policy"], p["stats"], e)
        xi_old, _ = xi_std(st.policy, st.obs_stats, e)
        fresh = np.asarray(data.fresh[e]).reshape(U * T)
        for t in np.flatnonzero(p["inside"][e]):
            s = int(np.flatnonzero(fresh[:t + 1])[-1])  # the trial's start
            C = dense_cov(proc, np.eye(1, t + 1 - s, 0, bool)[0])
            u0 = (t // T) * T  # the unroll's start: PPO's history before it is theta_old's
            hist_a = np.concatenate([xi_old[s:max(s, u0)], xi_new[max(s, u0):t + 1]])
            jac = np.sum(np.log(std_new[t]))
            b = dense_conditional_logpdf(C, xi_new[s:t + 1], t - s) - jac if t > s else None
            a = dense_conditional_logpdf(C, hist_a, t - s) - jac if t > s else None
            if b is None:
                continue
            assert p["b"][e, t] == pytest.approx(b, rel=1e-4, abs=1e-3)
            assert p["a"][e, t] == pytest.approx(a, rel=1e-4, abs=1e-3)
            checked += 1
    assert checked > 10
    assert np.max(np.abs(p["a"] - p["b"])[p["inside"]]) > 1e-4  # the update moved the earlier noise


def test_compare_refuses_a_process_with_periods():
    cfg = options.build(ppo_config.PPOConfig, **dict(TINY, exploration="nm-periods"))
    with pytest.raises(ValueError, match="ou, colored"):
        belief_ratio.parts(cfg, None, jax.random.PRNGKey(0), TinyEnv())
