"""Evaluate a policy trained on a Gymnasium task (``--env``, nmrl/tasks/): returns per episode.

A task is judged the way its literature judges it: the undiscounted return of an episode (the sum
of Gymnasium's per-step rewards from a reset until ``terminated`` or ``truncated``, at most the
task's time limit of 1,000 of its own steps) and the episode's length. :func:`episodes` runs
``n`` episodes side by side from Gymnasium's reset distribution (the task's reset noise, drawn
from ``seed``), each with the run's policy (nmrl/learners/contract.py, ``Policy``): deterministic
(``xi = 0``, Brax's mode) or exploring (the run's exploration noise). Steps after an episode's end
are computed and discarded (no automatic reset). At a control step finer than the task's own, each
reward is the task's reward times ``control_dt / dt0`` (nmrl/tasks/env.py), so the return still
sums the same reward per simulated second.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import learners
from nmrl.analysis import eval_env

#: episodes per evaluation (a mean over 10 episodes, as CleanRL's and most papers' evaluations)
EPISODES = 10


@functools.lru_cache(maxsize=8)
def _episodes_fn(program: Any, n: int):
    """A jitted ``(params, key, noise_scale, noise_args) -> per-step arrays (T, n)`` for ``n``
    episodes of the policy of ``program`` (its traced fields at their defaults)."""
    env = eval_env.of_config(program)
    pol = learners.of(program).policy(program, env)
    horizon = env.max_steps

    def run(params, key, noise_scale, noise_args):
        k_reset, k_eps = jax.random.split(key)
        s0 = jax.vmap(env.reset)(jax.random.split(k_reset, n))
        ns0 = jax.vmap(lambda _: pol.noise_init(env.act_dim))(jnp.arange(n))
        eps = jax.random.normal(k_eps, (horizon, n, env.act_dim), jnp.float32)

        def step(carry, e):
            s, ns, alive = carry
            ns, xi = jax.vmap(lambda st, ee: pol.noise_step(noise_args, st, ee))(ns, e)
            a = jax.vmap(lambda o, x: pol.act(params, o, noise_scale * x))(s.obs, xi)
            s = jax.vmap(env.step)(s, a)
            return (s, ns, alive & ~(s.done > 0)), _record(s, alive)

        _, traj = jax.lax.scan(step, (s0, ns0, jnp.ones((n,), bool)), eps)
        return traj

    return jax.jit(run)


def episodes(config: Any, params: dict, *, n: int = EPISODES, seed: int = 0, exploring: bool = False) -> dict:
    """``n`` episodes of a task run's policy: ``return`` (mean, sd, each), ``length`` (steps, each),
    ``terminated`` (episodes that ended by the task's rule before the time limit), ``forward_speed``
    (m/s, mean of Gymnasium's x velocity over the steps alive), ``nonfinite`` (failed physics steps)."""
    env = eval_env.of_config(config)
    noise_args = learners.of(config).policy(config, env).noise_args
    fn = _episodes_fn(learners.program_key(config), int(n))
    traj = jax.device_get(fn(params, jax.random.PRNGKey(seed), jnp.float32(1.0 if exploring else 0.0), noise_args))
    return _summary(traj, int(n))


def _summary(traj: dict, n: int) -> dict:
    ret = np.asarray(traj["reward"], np.float64).sum(axis=0)
    length = np.asarray(traj["alive"]).sum(axis=0)
    alive = np.asarray(traj["alive"])
    speed = float(np.asarray(traj["x_velocity"], np.float64).sum() / max(int(alive.sum()), 1))
    return {"episodes": int(n), "return": {"mean": float(ret.mean()), "sd": float(ret.std(ddof=1)) if n > 1 else 0.0,
                                           "each": [float(r) for r in ret]},
            "length": [int(x) for x in length], "terminated": int(np.asarray(traj["terminated"]).any(axis=0).sum()),
            "forward_speed": speed, "nonfinite": int(np.asarray(traj["nonfinite"]).sum())}


def _record(s: Any, alive: jax.Array) -> dict:
    """One step's per-episode values, zero after the episode's end."""
    return {"reward": jnp.where(alive, s.reward, 0.0), "alive": alive,
            "x_velocity": jnp.where(alive, s.metrics["x_velocity"], 0.0),
            "terminated": alive & (s.info["terminated"] > 0), "nonfinite": alive & (s.metrics["nonfinite"] > 0)}


@functools.lru_cache(maxsize=8)
def _act_episodes_fn(act: Any, name: str, control_dt: float, physics: str, n: int):
    """A jitted ``(params, key) -> per-step arrays (T, n)`` of ``n`` episodes of ``act(params, obs)``
    (another trainer's deterministic policy), from the reset states :func:`episodes` draws from ``key``."""
    env = _env(name, control_dt, physics)

    def run(params, key):
        k_reset, _ = jax.random.split(key)
        s0 = jax.vmap(env.reset)(jax.random.split(k_reset, n))

        def step(carry, _):
            s, alive = carry
            s = jax.vmap(env.step)(s, jax.vmap(lambda o: act(params, o))(s.obs))
            return (s, alive & ~(s.done > 0)), _record(s, alive)

        _, traj = jax.lax.scan(step, (s0, jnp.ones((n,), bool)), None, length=env.max_steps)
        return traj

    return jax.jit(run)


def act_episodes(act: Any, params: Any, name: str, control_dt: float, physics: str = "mjx", *,
                 n: int = EPISODES, seed: int = 0) -> dict:
    """:func:`episodes` for a policy given as ``act(params, obs) -> action`` (e.g. Brax PPO's mode,
    nmrl/experiments/baseline_ppo.py) on the task ``name``: the same reset states for the same ``seed``,
    the same summary."""
    fn = _act_episodes_fn(act, name, float(control_dt), physics, int(n))
    return _summary(jax.device_get(fn(params, jax.random.PRNGKey(seed))), int(n))
