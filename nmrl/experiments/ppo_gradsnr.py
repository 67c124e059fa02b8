"""Signal-to-noise ratio of PPO's policy-gradient estimate, per exploration process and control step.

The paper's eq. (1) argument: with a stationary policy at a fine control step, one action's
perturbation changes the return less and less, so the policy gradient estimated from a fixed amount
of experience grows noisier relative to its mean. For PPO the estimate is the gradient of its
surrogate at theta_old (every ratio 1, nothing clipped): from one environment's experience in one
iteration (U unrolls of ``unroll_s``, 102.4 s at the study's settings),

    g_e = grad_theta  (1 / (U T)) sum_{u,t} A_{e,u,t} log pi_theta(x_{e,u,t} | x since the last reset),

with A the GAE advantages under the current value net (docs/ppo.md), normalised over the whole
iteration's data as PPO normalises a minibatch, and log pi the process's exact conditional density
(nmrl/learners/ppo.py ``seq_logp``). The environments' g_e are independent estimates of one mean;
nmrl.experiments.gradvar.summarize turns per-batch sums into tr Cov(g_e), |E g_e|^2 (unbiased) and
the SNR of one second of one environment's experience, |E g|^2 / (tr Cov(g) * U * unroll_s), with
95% intervals over batches (independent rollouts from the same parameters).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from nmrl.experiments import gradvar
from nmrl.learners import ppo_losses as L
from nmrl.learners import ppo_networks as nn_
from nmrl.learners.ppo import PPOConfig, PPOState, make_ppo


def make_batch(cfg: PPOConfig, env: Any = None):
    """``batch(state, key) -> (state, (n, g_sum, g_sqnorm))``: one iteration's rollout from ``state``
    (its parameters unchanged, its environments and noise carried on) and the sums of the
    per-environment gradient estimates g_e over its ``num_envs`` environments (``env``: as for
    make_ppo)."""
    cfg = cfg.resolved()
    tr = make_ppo(cfg, env)
    U, T = cfg.unrolls_per_env, cfg.unroll_length

    def batch(st: PPOState, key: jax.Array):
        (es, ns, _), data = tr.rollout(st, key)  # data (N, U, T, ...)
        h = st.hyper
        obs_n = nn_.normalize(st.obs_stats, data.obs, cfg.normalize_obs)
        values = nn_.value(tr.nets, st.value, obs_n)  # (N, U, T)
        boot = nn_.value(tr.nets, st.value, nn_.normalize(st.obs_stats, data.next_obs, cfg.normalize_obs))

        def adv_of(r, v, b, term, trunc):  # (U, T) each, b (U,) -> advantages (U, T)
            tm = lambda a: jnp.swapaxes(a, 0, 1)  # noqa: E731
            _, a = L.gae(tm(r * h.reward_scale), tm(v), b, tm(term), tm(trunc), h.gamma, h.lam)
            return tm(a)

        adv = jax.vmap(adv_of)(data.reward, values, boot, data.termination, data.truncation)
        if cfg.normalize_advantage:
            adv = (adv - jnp.mean(adv)) / (jnp.std(adv) + 1e-8)
        flat0, unravel = ravel_pytree(st.policy)

        def one(args):
            d_e, a_e = args

            def obj(p):
                return jnp.sum(a_e * tr.seq_logp(p, st.obs_stats, d_e, h.process)) / (U * T)

            return ravel_pytree(jax.grad(obj)(st.policy))[0]

        g = jax.lax.map(one, (data, adv))  # (N, P)
        return st.replace(env=es, noise=ns), (jnp.float32(g.shape[0]), jnp.sum(g, 0), jnp.sum(g * g))

    return batch


_JITTED: dict = {}


def _jitted(cfg: PPOConfig, env: Any):
    """One compiled batch function per (config, environment): the initial and the mid-training
    policy of a run are measured by the same program."""
    k = (cfg, id(env))
    if k not in _JITTED:
        _JITTED[k] = jax.jit(make_batch(cfg, env))
    return _JITTED[k]


def measure(cfg: PPOConfig, state: PPOState, *, batches: int, seed: int = 0, warmup: int = 1, env: Any = None
            ) -> dict:
    """SNR statistics (gradvar.summarize's keys) of ``state``'s policy under ``cfg``: ``warmup``
    uncounted rollouts (all environments start from the reset pose together), then ``batches``."""
    if not (isinstance(batches, int) and batches >= 2):
        raise ValueError(f"batches={batches!r} is invalid: need an integer >= 2 for an interval")
    cfg = cfg.resolved()
    fn = _jitted(cfg, env)
    n, gs, gq = [], [], []
    key = jax.random.PRNGKey(seed)
    for b in range(warmup + batches):
        key, k = jax.random.split(key)
        state, (nb, g_sum, g_sq) = fn(state, k)
        if b < warmup:
            continue
        nb, g_sum, g_sq = jax.device_get((nb, g_sum, g_sq))
        n.append(float(nb))
        gs.append(np.asarray(g_sum, np.float64))
        gq.append(float(g_sq))
    out = gradvar.summarize(np.array(n), np.stack(gs), np.array(gq), cfg.unrolls_per_env * cfg.unroll_s)
    out["seconds_per_estimate"] = cfg.unrolls_per_env * cfg.unroll_s
    return out


def initial_state(cfg: PPOConfig, seed: int = 0, env: Any = None) -> PPOState:
    """The state a run of ``cfg`` with ``seed`` starts from (its initial policy)."""
    cfg = dataclasses.replace(cfg, seed=seed).resolved()
    return make_ppo(cfg, env).init(jax.random.PRNGKey(seed))


__all__: Any = ("make_batch", "measure", "initial_state")
