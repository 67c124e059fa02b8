"""The gradient's signal-to-noise estimate of PPO (nmrl/experiments/ppo_gradsnr.py): per-environment
sums against a plain-NumPy GAE and the normal density of ``jax.scipy.stats``, and several policies
measured side by side against one at a time."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import options

REPO = pathlib.Path(__file__).resolve().parents[1]


def test_gradient_estimate_per_environment_matches_an_independent_computation():
    """make_batch's sums of g_e = grad (1/UT) sum A log pi, for white noise, against GAE in NumPy
    (by its definition) and the normal density of jax.scipy.stats on the policy's mean and std."""
    from tests.test_ppo import TINY, _np_gae
    from tests.tiny_env import TinyEnv
    from jax.flatten_util import ravel_pytree
    from nmrl.experiments import ppo_gradsnr
    from nmrl.learners import ppo, ppo_config
    from nmrl.learners import ppo_networks as nn_

    cfg = options.build(ppo_config.PPOConfig, **dict(TINY, num_envs=3, batch_size=6), exploration="white", reward_scale=0.5).resolved()
    env = TinyEnv(stop_prob=0.1)
    tr = ppo.make_ppo(cfg, env)
    st = tr.init(jax.random.PRNGKey(1))
    st = st.replace(obs_stats=st.obs_stats._replace(mean=st.obs_stats.mean + 0.1))
    key = jax.random.PRNGKey(7)
    new, (n, g_sum, g_sq) = jax.jit(ppo_gradsnr.make_batch(cfg, env))(st, key)
    (_, _, _), data = jax.jit(tr.rollout)(st, key)  # the same rollout (same state, same key)
    h = st.hyper
    N, U, T = data.reward.shape
    obs_n = nn_.normalize(st.obs_stats, data.obs)
    v = np.asarray(nn_.value(tr.nets, st.value, obs_n), np.float64)
    boot = np.asarray(nn_.value(tr.nets, st.value, nn_.normalize(st.obs_stats, data.next_obs)), np.float64)
    adv = np.zeros((N, U, T))
    for e in range(N):
        _, a = _np_gae(np.asarray(data.reward[e], np.float64).T * float(h.reward_scale), v[e].T, boot[e],
                       np.asarray(data.termination[e]).T > 0, np.asarray(data.truncation[e]).T > 0,
                       float(h.gamma), float(h.lam))
        adv[e] = a.T
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    grads = []
    for e in range(N):
        def obj(p):
            mu, std = nn_.mean_std(tr.nets, p, obs_n[e], cfg.min_std)
            lp = jnp.sum(jax.scipy.stats.norm.logpdf(data.x[e], mu, std), axis=-1)
            return jnp.sum(jnp.asarray(adv[e], jnp.float32) * lp) / (U * T)
        grads.append(np.asarray(ravel_pytree(jax.grad(obj)(st.policy))[0], np.float64))
    grads = np.stack(grads)
    assert float(n) == N
    np.testing.assert_allclose(np.asarray(g_sum), grads.sum(0), rtol=2e-4, atol=1e-6)
    np.testing.assert_allclose(float(g_sq), np.sum(grads ** 2), rtol=2e-4)
    assert int(new.step) == int(st.step)  # no learning: the counters and parameters stay
    np.testing.assert_array_equal(ravel_pytree(new.policy)[0], ravel_pytree(st.policy)[0])


_SIDE_BY_SIDE = """
import json, jax, numpy as np
from nmrl import options
from nmrl.experiments import gradvar, ppo_gradsnr
from nmrl.learners import ppo, ppo_config
from tests.test_ppo import TINY
from tests.tiny_env import TinyEnv
assert jax.local_device_count() == 2, jax.devices()
cfg = options.build(ppo_config.PPOConfig, **dict(TINY, num_envs=3, batch_size=6), exploration="ou", reward_scale=0.5).resolved()
env = TinyEnv(stop_prob=0.1)
tr = ppo.make_ppo(cfg, env)
states = [tr.init(jax.random.PRNGKey(s)) for s in (1, 2, 3)]
many = ppo_gradsnr.measure_many(cfg, states, batches=2, seed=5, warmup=1, env=env)
batch = jax.jit(ppo_gradsnr.make_batch(cfg, env))
plain = []
for st in states:  # one policy at a time: the warm-up rollout, then two counted ones
    key, sums = jax.random.PRNGKey(5), []
    for b in range(3):
        key, k = jax.random.split(key)
        st, s = batch(st, k)
        if b:
            sums.append(jax.device_get(s))
    n, g, q = (np.array([np.asarray(x[i], np.float64) for x in sums]) for i in range(3))
    plain.append(gradvar.summarize(n, g, q, cfg.unrolls_per_env * cfg.unroll_s))
print(json.dumps([many, plain]))
"""


def test_policies_measured_side_by_side_on_two_devices_match_one_at_a_time(tmp_path):
    """measure_many over 2 devices (3 policies: one device holds two, one slot idle) gives each
    policy what a plain loop of the batch function (checked above against NumPy) gives it alone."""
    import os

    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu",
           "PYTHONPATH": str(REPO)}
    p = subprocess.run([sys.executable, "-c", _SIDE_BY_SIDE], env=env, cwd=REPO, capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    many, plain = json.loads(p.stdout.strip().splitlines()[-1])
    assert len(many) == len(plain) == 3
    assert len({round(m["trcov"], 9) for m in many}) == 3  # three different policies
    for m, q in zip(many, plain):
        assert (m["periods"], m["batches"]) == (q["periods"], q["batches"]) == (6, 2)
        for k in ("trcov", "trcov_ci", "mean_sq", "mean_sq_ci", "snr_per_s"):
            np.testing.assert_allclose(m[k], q[k], rtol=1e-3, atol=1e-9, err_msg=k)
