"""The deterministic policy's reward per second, from perturbed starts: a study's endpoint.

A policy's quality is its mean action's, not its exploring behaviour's (at a fixed per-step
noise scale, white noise disturbs the robot less at a finer control step, so an exploring reward
mixes the policy with its noise). :func:`deterministic_endpoint` rolls the learner's deterministic
policy (``act(params, obs, 0)``, nmrl/learners/contract.py) out ``rollouts`` times for ``seconds``
from the paper's initial pose with the joints perturbed (``HalfCheetah.perturb``: U(-s, s) rad,
s N(0, 1) rad/s), trials never stopping, and reports each rollout's mean reward per step divided
by the paper's 0.02 s (reward per second, nmrl/experiments/timescale.py), on the run's physics.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import learners
from nmrl.paper.env import HalfCheetah

DELTA_0 = 0.02  #: the paper's control step: reward per second = mean r_t / DELTA_0
START_NOISE = 0.05  #: rad (angles, uniform half-width) and rad/s (velocities, standard deviation)


@functools.lru_cache(maxsize=8)
def _program(program: Any, n_steps: int, rollouts: int, start_noise: float):
    cfg = program
    # the run's own environment (physics, its timestep), trials never stopping
    env = HalfCheetah(dataclasses.replace(cfg.env_config(), stop_prob=0.0, trial_s=None, auto_reset=False))
    pol = learners.of(cfg).policy(cfg, env)

    def one(params, key):
        k_reset, k_start = jax.random.split(key)
        s = env.perturb(env.reset(k_reset), k_start, start_noise)
        zero = jnp.zeros(env.act_dim, jnp.float32)

        def step(s, _):
            s = env.step(s, pol.act(params, s.obs, zero))
            return s, (s.reward, s.metrics["forward_speed"], s.metrics["nonfinite"])

        _, (r, v, bad) = jax.lax.scan(step, s, None, length=n_steps)
        return r.mean(), v.mean(), bad.sum()

    return jax.jit(lambda params, keys: jax.vmap(one, in_axes=(None, 0))(params, keys))


def deterministic_endpoint(config: Any, params: dict, *, seconds: float = 10.0, rollouts: int = 8,
                           start_noise: float = START_NOISE, seed: int = 0) -> dict:
    """``{"reward_per_s": mean over rollouts, "rollouts": [per rollout], "forward_speed": [m/s per
    rollout], "nonfinite_steps": int, ...}`` of ``params`` ({field: tree} of the learner's
    ``policy_fields``) under ``config``."""
    if not (isinstance(rollouts, int) and rollouts >= 1):
        raise ValueError(f"rollouts={rollouts!r} is invalid: must be an integer >= 1")
    if not (np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds={seconds!r} is invalid: must be a finite time > 0 s")
    n_steps = max(1, int(round(seconds / config.control_dt)))
    fn = _program(learners.program_key(config), n_steps, rollouts, float(start_noise))
    keys = jax.random.split(jax.random.PRNGKey(seed), rollouts)
    r, v, bad = (np.asarray(x, np.float64) for x in fn(params, keys))
    per_s = r / DELTA_0
    return {"reward_per_s": float(per_s.mean()), "rollouts": per_s.tolist(), "forward_speed": v.tolist(),
            "nonfinite_steps": int(bad.sum()), "seconds": n_steps * config.control_dt, "start_noise": start_noise,
            "seed": seed}
