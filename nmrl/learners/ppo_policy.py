"""PPO's evaluation policy (nmrl/learners/contract.py's ``Policy``): the run's squashed Gaussian
policy with its exploration process, or deterministic with xi = 0."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from nmrl import explore
from nmrl.learners import ppo_networks as nn_
from nmrl.learners.contract import Policy
from nmrl.learners.ppo_config import PPOConfig


def policy(cfg: PPOConfig, env: Any) -> Policy:
    """``act(params, obs, xi) = squash(mu_theta(s) + std_theta(s) xi)`` onto the environment's action
    range (the paper's robot: 20 tanh(.); ``ppo_networks.action_range``) with ``s`` the
    observation through the run's normaliser (``params``: ``policy``, ``obs_stats``); xi = 0 is the
    deterministic policy (Brax's mode: tanh of the mean). The exploring policy's noise is the run's
    process, drawn by nmrl.explore.sample from a key made of the per-step ``eps``'s bits."""
    cfg = cfg.resolved()
    nets = nn_.make_networks(cfg.policy_layers, cfg.policy_width, cfg.value_layers, cfg.value_width, env.act_dim,
                             cfg.learn_std)
    proc = cfg.noise.spec().process(cfg.environment.control_dt)
    scale = nn_.action_range(env)

    def act(params, obs, xi):
        mu, std = nn_.mean_std(nets, params["policy"], nn_.normalize(params["obs_stats"], obs, cfg.normalize_obs),
                               cfg.min_std)
        return nn_.squash(mu + std * xi, cfg.squash, *scale)

    def noise_init(act_dim):
        return explore.init(proc, jax.random.PRNGKey(0), 1, act_dim)

    def noise_step(p, state, eps):
        bits = jax.lax.bitcast_convert_type(jnp.asarray(eps, jnp.float32), jnp.uint32)
        key = jax.random.PRNGKey(0)
        for j in range(bits.shape[0]):
            key = jax.random.fold_in(key, bits[j])
        xi, _, _, state = explore.sample(p, state, key)
        return state, xi[0]

    return Policy(act=act, noise_init=noise_init, noise_step=noise_step, noise_args=proc)
