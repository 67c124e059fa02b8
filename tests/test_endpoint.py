"""The deterministic endpoint and the noisy one (nmrl/analysis/endpoint.py) and the perturbed start they use."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from nmrl import options
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
    cfg = options.build(PPOConfig, num_envs=4, batch_size=4, num_minibatches=1, value_layers=1, value_width=8,
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
    cfg = options.build(PPOConfig, num_envs=4, batch_size=4, num_minibatches=1, value_layers=1, value_width=8, policy_layers=1,
                    policy_width=8, control_dt=0.0025, physics_timestep=0.0025, physics="c").resolved()
    st = make_ppo(cfg).init(jax.random.PRNGKey(0))
    params = {"policy": st.policy, "obs_stats": st.obs_stats}
    out = endpoint.deterministic_endpoint(cfg, params, seconds=0.1, rollouts=2)
    assert out["seconds"] == pytest.approx(0.1) and len(out["rollouts"]) == 2
    ref = evaluate.rollout_params(cfg, params, seconds=0.1, seed=0, exploring=False)
    assert len(ref["reward"]) == 40


@pytest.mark.parametrize("exploration", [{"exploration": "white", "sigma": 0.7},
                                         {"exploration": "ou", "sigma": 0.5, "corr_time_s": 0.06}],
                         ids=["white", "ou"])
def test_the_noisy_endpoint_is_a_plain_loop_of_the_policy_with_its_scaled_noise(exploration):
    """Each rollout of ``noisy_endpoint`` against a Python loop over the environment's single step:
    the endpoint's start (``split(key)``), N(0, I) draws from ``fold_in(key, 1)`` through the run's
    process (its sigma, and for OU its state carried from step to step), the action ``act(obs, k xi)``."""
    from nmrl.analysis import eval_env
    from nmrl.learners import ppo_policy

    cfg = options.build(PPOConfig, num_envs=4, batch_size=4, num_minibatches=1, value_layers=1, value_width=8, policy_layers=1,
                    policy_width=8, physics="c", **exploration).resolved()
    st = make_ppo(cfg).init(jax.random.PRNGKey(0))
    params = {"policy": st.policy, "obs_stats": st.obs_stats}
    k, n, rollouts = 0.6, 10, 2
    out = endpoint.noisy_endpoint(cfg, params, k, seconds=n * 0.02, rollouts=rollouts, seed=4)
    env = eval_env.of_config(cfg)
    pol = ppo_policy.policy(cfg, env)
    ref, speeds = [], []
    for key in jax.random.split(jax.random.PRNGKey(4), rollouts):
        k_reset, k_start = jax.random.split(key)
        s = env.perturb(env.reset(k_reset), k_start, endpoint.START_NOISE)
        eps = np.asarray(jax.random.normal(jax.random.fold_in(key, 1), (n, env.act_dim), np.float32))
        ns = pol.noise_init(env.act_dim)
        r, v = [], []
        for t in range(n):
            ns, xi = pol.noise_step(pol.noise_args, ns, eps[t])
            s = env.step(s, pol.act(params, s.obs, k * np.asarray(xi)))
            r.append(float(s.reward))
            v.append(float(s.metrics["forward_speed"]))
        ref.append(np.mean(r) / 0.02)
        speeds.append(np.mean(v))
    assert out["rollouts"] == pytest.approx(ref, rel=1e-3)
    assert out["forward_speed"] == pytest.approx(speeds, rel=1e-3, abs=1e-4)
    assert out["noise_scale"] == k
    # k = 0 is the deterministic endpoint, to the bit; a different k moves the result
    det = endpoint.deterministic_endpoint(cfg, params, seconds=n * 0.02, rollouts=rollouts, seed=4)
    assert endpoint.noisy_endpoint(cfg, params, 0.0, seconds=n * 0.02, rollouts=rollouts, seed=4)["rollouts"] \
        == det["rollouts"]
    assert out["rollouts"] != det["rollouts"]
    with pytest.raises(ValueError, match="noise_scale=-1"):
        endpoint.noisy_endpoint(cfg, params, -1.0)
