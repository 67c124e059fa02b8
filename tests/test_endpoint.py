"""The deterministic endpoint (nmrl/analysis/endpoint.py) and the perturbed start it uses."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from nmrl.analysis import endpoint, evaluate
from nmrl.learners.ppo import make_ppo
from nmrl.learners.ppo_config import PPOConfig
from nmrl.paper.env import EnvConfig, HalfCheetah


@pytest.mark.parametrize("physics", ["mjx", "c"])
def test_perturb_moves_the_joints_only_within_the_scale(physics):
    env = HalfCheetah(EnvConfig(physics=physics, auto_reset=False, stop_prob=0.0))
    s0 = env.reset(jax.random.PRNGKey(0))
    a = env.perturb(s0, jax.random.PRNGKey(1), 0.05)
    b = env.perturb(s0, jax.random.PRNGKey(2), 0.05)
    dq = np.asarray(a.data.qpos) - np.asarray(s0.data.qpos)
    assert np.all(dq[:3] == 0) and 0 < np.max(np.abs(dq[3:])) <= 0.05 + 1e-7
    assert not np.allclose(np.asarray(a.data.qpos), np.asarray(b.data.qpos))
    assert not np.allclose(np.asarray(a.obs), np.asarray(s0.obs))
    # the step continues from the perturbed state: its first step differs from the unperturbed one's
    z = np.zeros(6, np.float32)
    assert not np.allclose(np.asarray(env.step(a, z).data.qpos), np.asarray(env.step(s0, z).data.qpos))


def test_perturb_is_the_same_on_both_physics():
    s = [HalfCheetah(EnvConfig(physics=p, auto_reset=False, stop_prob=0.0)) for p in ("mjx", "c")]
    a, b = (e.perturb(e.reset(jax.random.PRNGKey(0)), jax.random.PRNGKey(3), 0.05) for e in s)
    np.testing.assert_allclose(np.asarray(a.data.qpos), np.asarray(b.data.qpos), atol=1e-6)
    np.testing.assert_allclose(np.asarray(a.obs), np.asarray(b.obs), atol=1e-5)


def test_endpoint_without_noise_is_the_deterministic_rollout_of_nmrl_eval():
    cfg = PPOConfig(num_envs=4, batch_size=4, num_minibatches=1, value_layers=1, value_width=8,
                    policy_layers=1, policy_width=8).resolved()
    st = make_ppo(cfg).init(jax.random.PRNGKey(0))
    params = {"policy": st.policy, "obs_stats": st.obs_stats}
    # 0.3 s: the untrained policy flails, and after ~1 s float rounding (vmap vs a single rollout) has
    # grown into a different trajectory
    out = endpoint.deterministic_endpoint(cfg, params, seconds=0.3, rollouts=3, start_noise=0.0)
    ref = evaluate.rollout_params(cfg, params, seconds=0.3, seed=0, exploring=False)
    assert out["rollouts"] == pytest.approx([np.mean(ref["reward"], dtype=np.float64) / 0.02] * 3, rel=1e-5)
    noisy = endpoint.deterministic_endpoint(cfg, params, seconds=1.0, rollouts=3)
    assert len(set(noisy["rollouts"])) == 3 and noisy["nonfinite_steps"] == 0
    with pytest.raises(ValueError, match="rollouts"):
        endpoint.deterministic_endpoint(cfg, params, rollouts=0)


def test_endpoint_and_eval_use_the_runs_physics_timestep():
    """A 2.5 ms run on a 2.5 ms physics timestep: its endpoint and eval rollouts step that physics
    (the model's own 5 ms timestep cannot make a 2.5 ms control step)."""
    cfg = PPOConfig(num_envs=4, batch_size=4, num_minibatches=1, value_layers=1, value_width=8, policy_layers=1,
                    policy_width=8, control_dt=0.0025, physics_timestep=0.0025, physics="c").resolved()
    st = make_ppo(cfg).init(jax.random.PRNGKey(0))
    params = {"policy": st.policy, "obs_stats": st.obs_stats}
    out = endpoint.deterministic_endpoint(cfg, params, seconds=0.1, rollouts=2)
    assert out["seconds"] == pytest.approx(0.1) and len(out["rollouts"]) == 2
    ref = evaluate.rollout_params(cfg, params, seconds=0.1, seed=0, exploring=False)
    assert len(ref["reward"]) == 40
