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
With ``period_wise`` (nm-periods learned on periods as wholes) a sample is a period: g_e sums
A_p log pi_theta(period p) over the period starts p, with the period-wise advantages
(nmrl/learners/ppo_losses.py ``period_gae``), normalised over the periods, and the period's
density (eq. (7): the sum of its steps' conditionals, ``segment_sums``), as PPO's period-wise loss
learns from them. nmrl.experiments.gradvar.summarize turns per-batch sums into tr Cov(g_e), |E g_e|^2 (unbiased) and
the SNR of one second of one environment's experience, |E g|^2 / (tr Cov(g) * U * unroll_s), with
95% intervals over batches (independent rollouts from the same parameters).
"""

from __future__ import annotations

from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from nmrl.experiments import gradvar
from nmrl import options
from nmrl.learners import ppo_losses as L
from nmrl.learners import ppo_networks as nn_
from nmrl.learners.ppo import PPOState, make_ppo
from nmrl.learners.ppo_config import PPOConfig
from nmrl.runs import points


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

        def period_adv_of(r, v, b, term, trunc, fresh):  # per period: (U, T), 0 off period starts
            tm = lambda a: jnp.swapaxes(a, 0, 1)  # noqa: E731
            start = tm(fresh).at[0].set(True)
            _, a = L.period_gae(tm(r * h.reward_scale), tm(v), b, tm(term), tm(trunc), start, h.gamma, h.lam)
            return tm(a), tm(start.astype(a.dtype))

        if cfg.period_wise:
            adv, w = jax.vmap(period_adv_of)(data.reward, values, boot, data.termination, data.truncation,
                                             data.fresh)
            if cfg.normalize_advantage:  # over the periods, as PPO's period-wise loss
                adv = L.normalize_advantages(adv, jnp.sum(adv * w), jnp.sum(w), jnp.sum(adv * adv * w)) * w
        else:
            adv = jax.vmap(adv_of)(data.reward, values, boot, data.termination, data.truncation)
            if cfg.normalize_advantage:
                adv = (adv - jnp.mean(adv)) / (jnp.std(adv) + 1e-8)

        def one(args):
            d_e, a_e = args

            def obj(p):
                logp = tr.seq_logp(p, st.obs_stats, d_e, h.process)  # (U, T)
                if cfg.period_wise:  # a period's density (eq. (7)), at its start
                    logp = jnp.swapaxes(L.segment_sums(jnp.swapaxes(logp, 0, 1), jnp.swapaxes(d_e.fresh, 0, 1)),
                                        0, 1)
                return jnp.sum(a_e * logp) / (U * T)

            return ravel_pytree(jax.grad(obj)(st.policy))[0]

        g = jax.lax.map(one, (data, adv))  # (N, P)
        return st.replace(env=es, noise=ns), (jnp.float32(g.shape[0]), jnp.sum(g, 0), jnp.sum(g * g))

    return batch


_PROGRAMS: dict = {}


def _program(cfg: PPOConfig, env: Any, num_devices: int):
    """One compiled program per (config, environment, devices): the policies' batches side by side,
    a slot's state carrying its key, laid out as a sweep's points (nmrl/runs/points.py: one slot
    per device at a time, no communication)."""
    k = (cfg, id(env), num_devices)
    if k not in _PROGRAMS:
        batch = make_batch(cfg, env)

        def chunk(slot):
            st, key = slot
            st, sums = batch(st, key)
            return (st, key), sums

        _PROGRAMS[k] = jax.jit(points.points_program(chunk, num_devices))
    return _PROGRAMS[k]


def measure_many(cfg: PPOConfig, states: Sequence[PPOState], *, batches: int, seed: int = 0, warmup: int = 1,
                 env: Any = None, num_devices: int | None = None) -> list[dict]:
    """SNR statistics (gradvar.summarize's keys) of each of ``states``' policies under ``cfg``, the
    policies measured side by side over ``num_devices`` local devices (default: all, at most one
    per policy): ``warmup`` uncounted rollouts (all environments start from the reset pose
    together), then ``batches``; every policy sees the same key sequence (PRNGKey(seed), split
    once per batch)."""
    if not (isinstance(batches, int) and batches >= 2):
        raise ValueError(f"batches={batches!r} is invalid: need an integer >= 2 for an interval")
    if not states:
        return []
    cfg = cfg.resolved()
    d = min(len(states), jax.local_device_count() if num_devices is None else num_devices)
    slots = points.slot_order(len(states), d)
    stacked = points.stack_trees([states[max(i, 0)] for i in slots])
    active = points.place_points(jnp.array([i >= 0 for i in slots]), d)
    fn = _program(cfg, env, d)
    n = [[] for _ in states]
    gs = [[] for _ in states]
    gq = [[] for _ in states]
    key = jax.random.PRNGKey(seed)
    for b in range(warmup + batches):
        key, k = jax.random.split(key)
        keys = jnp.broadcast_to(k, (len(slots),) + k.shape)
        (stacked, _), (nb, g_sum, g_sq) = fn(points.place_points((stacked, keys), d), active)
        if b < warmup:
            continue
        nb, g_sum, g_sq = jax.device_get((nb, g_sum, g_sq))
        for j, i in enumerate(slots):
            if i >= 0:
                n[i].append(float(nb[j]))
                gs[i].append(np.asarray(g_sum[j], np.float64))
                gq[i].append(float(g_sq[j]))
    out = []
    for i in range(len(states)):
        r = gradvar.summarize(np.array(n[i]), np.stack(gs[i]), np.array(gq[i]), cfg.unrolls_per_env * cfg.unroll_s)
        r["seconds_per_estimate"] = cfg.unrolls_per_env * cfg.unroll_s
        out.append(r)
    return out


def measure(cfg: PPOConfig, state: PPOState, *, batches: int, seed: int = 0, warmup: int = 1, env: Any = None
            ) -> dict:
    """:func:`measure_many` of one policy (on one device)."""
    return measure_many(cfg, [state], batches=batches, seed=seed, warmup=warmup, env=env, num_devices=1)[0]


def initial_state(cfg: PPOConfig, seed: int = 0, env: Any = None) -> PPOState:
    """The state a run of ``cfg`` with ``seed`` starts from (its initial policy)."""
    cfg = options.replace(cfg, seed=seed).resolved()
    return make_ppo(cfg, env).init(jax.random.PRNGKey(seed))


__all__: Any = ("make_batch", "measure", "measure_many", "initial_state")
