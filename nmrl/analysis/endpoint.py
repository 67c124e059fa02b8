"""The deterministic policy's reward per second, from perturbed starts: a study's endpoint.

A policy's quality is its mean action's, not its exploring behaviour's (at a fixed per-step
noise scale, white noise disturbs the robot less at a finer control step, so an exploring reward
mixes the policy with its noise). :func:`deterministic_endpoint` rolls the learner's deterministic
policy (``act(params, obs, 0)``, nmrl/learners/contract.py) out ``rollouts`` times for ``seconds``
in the run's own environment (its ``env``, physics and timestep; nmrl/analysis/eval_env.py):

* the paper's robot starts from the paper's initial pose with the joints perturbed
  (``HalfCheetah.perturb``: U(-s, s) rad, s N(0, 1) rad/s), trials never stopping, and each rollout
  reports its mean reward per step divided by the paper's 0.02 s (reward per second,
  nmrl/experiments/timescale.py);
* a Gymnasium task starts from its own reset distribution (Gymnasium's reset noise; ``start_noise``
  does not apply) and runs one episode: a rollout reports the sum of its rewards until the task
  terminates it (a fall of Hopper or Walker2d) divided by the seconds simulated, at most the task's
  time limit. The task's rewards are rates integrated over the control step (docs/tasks.md), so
  this is the return per simulated second at every control step, and a fall forfeits the rest.

:func:`noisy_endpoint` is the same rollouts with the run's own exploration noise multiplied by a
scale k (``act(params, obs, k xi_t)``, xi_t the learner's process, nmrl/learners/contract.py's
``Policy``): the same starts as the deterministic endpoint's, and the same noise draws at every k,
so that k alone differs; k = 0 is the deterministic endpoint, k = 1 the exploring policy as it was
trained, evaluated like the deterministic one (trials never stopping).
"""

from __future__ import annotations

import functools
import numbers
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import learners, tasks
from nmrl.analysis import eval_env
from nmrl.paper.control_step import DELTA_0

START_NOISE = 0.05  #: rad (angles, uniform half-width) and rad/s (velocities, standard deviation)


def _is_task(cfg: Any) -> bool:
    return cfg.environment.env != tasks.PAPER


def _steps(cfg: Any, seconds: float) -> int:
    """Control steps of a rollout of ``seconds`` (a task's: at most its time limit)."""
    n = max(1, int(round(seconds / cfg.environment.control_dt)))
    return min(n, eval_env.of_config(cfg).max_steps) if _is_task(cfg) else n


@functools.lru_cache(maxsize=16)
def _program(program: Any, n_steps: int, rollouts: int, start_noise: float, noisy: bool = False):
    """The jitted rollouts ``(params, keys, scale, noise_args) -> (mean reward, mean forward speed,
    non-finite steps)`` per rollout; without ``noisy`` the action is ``act(params, obs, 0)`` (scale
    and noise_args unused), with it ``act(params, obs, scale xi_t)``, xi_t the learner's process
    driven by N(0, I) draws from ``fold_in(key, 1)`` (the start keeps ``split(key)``)."""
    cfg = program
    env = eval_env.of_config(cfg)  # the run's own environment, no automatic reset
    pol = learners.of(cfg).policy(cfg, env)
    task = _is_task(cfg)

    def one(params, key, scale, noise_args):
        k_reset, k_start = jax.random.split(key)
        s = env.reset(k_reset) if task else env.perturb(env.reset(k_reset), k_start, start_noise)
        zero = jnp.zeros(env.act_dim, jnp.float32)
        eps = jax.random.normal(jax.random.fold_in(key, 1), (n_steps, env.act_dim), jnp.float32) if noisy else None
        ns = pol.noise_init(env.act_dim) if noisy else ()

        def step(carry, e):
            s, ns, alive = carry
            if noisy:
                ns, xi = pol.noise_step(noise_args, ns, e)
                s = env.step(s, pol.act(params, s.obs, scale * xi))
            else:
                s = env.step(s, pol.act(params, s.obs, zero))
            out = (jnp.where(alive, s.reward, 0.0), jnp.where(alive, s.metrics["forward_speed"], 0.0),
                   jnp.where(alive, s.metrics["nonfinite"], 0.0))
            ended = (s.info["terminated"] > 0) if task else jnp.zeros((), bool)
            return (s, ns, alive & ~ended), out

        _, (r, v, bad) = jax.lax.scan(step, (s, ns, jnp.ones((), bool)), eps, length=n_steps)
        return r.mean(), v.mean(), bad.sum()

    return jax.jit(lambda params, keys, scale, noise_args:
                   jax.vmap(one, in_axes=(None, 0, None, None))(params, keys, scale, noise_args))


def deterministic_endpoint(config: Any, params: dict, *, seconds: float = 10.0, rollouts: int = 8,
                           start_noise: float = START_NOISE, seed: int = 0) -> dict:
    """``{"reward_per_s": mean over rollouts, "rollouts": [per rollout], "forward_speed": [m/s per
    rollout], "nonfinite_steps": int, ...}`` of ``params`` ({field: tree} of the learner's
    ``policy_fields``) under ``config`` (``start_noise``: None on a task, which starts from its own
    reset distribution)."""
    return _endpoint(config, params, None, seconds=seconds, rollouts=rollouts, start_noise=start_noise, seed=seed)


def noisy_endpoint(config: Any, params: dict, noise_scale: float, *, seconds: float = 10.0, rollouts: int = 8,
                   start_noise: float = START_NOISE, seed: int = 0) -> dict:
    """:func:`deterministic_endpoint`'s numbers for the policy with its exploration noise times
    ``noise_scale`` (k >= 0; see the module docstring), with ``noise_scale`` in the result."""
    if isinstance(noise_scale, bool) or not (isinstance(noise_scale, numbers.Real) and np.isfinite(noise_scale)
                                             and noise_scale >= 0):
        raise ValueError(f"noise_scale={noise_scale!r} is invalid: must be a finite number >= 0")
    return {**_endpoint(config, params, float(noise_scale), seconds=seconds, rollouts=rollouts,
                        start_noise=start_noise, seed=seed), "noise_scale": float(noise_scale)}


def _endpoint(config: Any, params: dict, noise_scale: float | None, *, seconds: float, rollouts: int,
              start_noise: float, seed: int) -> dict:
    if not (isinstance(rollouts, int) and rollouts >= 1):
        raise ValueError(f"rollouts={rollouts!r} is invalid: must be an integer >= 1")
    if not (np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds={seconds!r} is invalid: must be a finite time > 0 s")
    task = _is_task(config)
    n_steps = _steps(config, seconds)
    noisy = noise_scale is not None
    fn = _program(learners.program_key(config), n_steps, rollouts, 0.0 if task else float(start_noise), noisy)
    noise_args = learners.of(config).policy(config, eval_env.of_config(config)).noise_args if noisy else ()
    keys = jax.random.split(jax.random.PRNGKey(seed), rollouts)
    out = fn(params, keys, jnp.float32(noise_scale if noisy else 0.0), noise_args)
    r, v, bad = (np.asarray(x, np.float64) for x in out)
    per_s = r / config.environment.control_dt if task else r / DELTA_0
    return {"reward_per_s": float(per_s.mean()), "rollouts": per_s.tolist(), "forward_speed": v.tolist(),
            "nonfinite_steps": int(bad.sum()), "seconds": n_steps * config.environment.control_dt,
            "start_noise": None if task else start_noise, "seed": seed}
