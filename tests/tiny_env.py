"""A tiny deterministic-dynamics environment with the interface of ``nmrl.paper.env.HalfCheetah``.

Used by the learner tests so that a run takes seconds. A stable linear system

    x_{t+1} = A x_t + B a_t,    x in R^3, a in R^2,
    r_t = x_{t+1}[0] - 0.1 |x_{t+1}|^2 - 0.01 |a_t|^2      (terms "r_lin", "r_quad", "r_act"),

observed exactly (obs = x). After each step the trial is stopped with probability ``stop_prob``,
drawn from a key kept in ``state.info["key"]`` (split once per step, like HalfCheetah); with
``auto_reset`` a stopped trial restarts at ``X0`` inside ``step`` and ``done`` flags it. The only
randomness is that stop decision, so the dynamics are a plain function of the actions.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nmrl.paper.env import State

A = np.array([[0.9, 0.1, 0.0], [-0.1, 0.8, 0.1], [0.0, 0.2, 0.7]], np.float32)
B = np.array([[0.1, 0.0], [0.05, 0.1], [0.0, 0.1]], np.float32)
X0 = np.array([0.2, -0.1, 0.3], np.float32)
REWARD_TERMS = ("r_lin", "r_quad", "r_act")


def rewards(x_next: Any, a: Any, xp: Any = jnp) -> dict[str, Any]:
    """The reward terms for action ``a`` leading to ``x_next`` (``xp`` = jnp or numpy)."""
    return {
        "r_lin": x_next[0],
        "r_quad": -0.1 * xp.sum(x_next * x_next),
        "r_act": -0.01 * xp.sum(a * a),
    }


class TinyEnv:
    """See the module docstring. ``reset``/``step`` are pure and jit/vmap friendly."""

    obs_dim = 3
    act_dim = 2
    reward_terms = REWARD_TERMS

    def __init__(self, stop_prob: float = 0.1, auto_reset: bool = True):
        if not 0.0 <= stop_prob < 1.0:
            raise ValueError(f"stop_prob must be in [0, 1), got {stop_prob!r}")
        self.stop_prob = stop_prob
        self.auto_reset = auto_reset

    def reset(self, key: jax.Array) -> State:
        x = jnp.asarray(X0)
        zero = jnp.zeros((), jnp.float32)
        metrics = {k: zero for k in REWARD_TERMS}
        metrics.update(forward_speed=zero, nonfinite=zero)
        info = {"key": key, "steps": jnp.zeros((), jnp.int32)}
        return State(data={"x": x}, obs=x, reward=zero, done=zero, metrics=metrics, info=info)

    def step(self, state: State, action: jax.Array) -> State:
        action = jnp.asarray(action, jnp.float32)
        if action.shape != (self.act_dim,):
            raise ValueError(f"action must have shape ({self.act_dim},), got {action.shape}")
        x = state.data["x"]
        x_next = jnp.asarray(A) @ x + jnp.asarray(B) @ action
        terms = rewards(x_next, action)
        reward = sum(terms[k] for k in REWARD_TERMS)
        finite = jnp.all(jnp.isfinite(x_next))
        key, k_stop = jax.random.split(state.info["key"])
        stopped = (jax.random.uniform(k_stop) < self.stop_prob) | ~finite
        metrics = dict(terms)
        metrics.update(forward_speed=x_next[0], nonfinite=(~finite).astype(jnp.float32))
        steps = state.info["steps"] + 1
        x_out = x_next
        if self.auto_reset:
            x_out = jnp.where(stopped, jnp.asarray(X0), x_next)
            steps = jnp.where(stopped, 0, steps)
        info = {"key": key, "steps": steps}
        return State(data={"x": x_out}, obs=x_out, reward=reward, done=stopped.astype(jnp.float32),
                     metrics=metrics, info=info)
