"""Gymnasium's v5 tasks (nmrl/tasks/: HalfCheetah, Hopper, Walker2d) as Brax environments, for Brax's PPO.

``BraxTask(name, control_dt, physics)`` satisfies ``brax.envs.Env`` like
:class:`nmrl.adapters.brax_env.BraxHalfCheetah` does for the paper's robot: ``observation_size``,
``action_size``, ``backend``, ``dt``, ``reset(rng)`` and ``step(state, action)`` on a Brax ``State``
whose ``pipeline_state`` is the task's physics data (MJX data, or MuJoCo C's float64 state on
``physics="c"``). One ``step`` is one control step of :class:`nmrl.tasks.env.Task` (the task's own
step unless ``control_dt`` is given), built with ``auto_reset=False``: Brax's ``AutoResetWrapper``
restarts an ended episode from the state ``reset`` made.

How an episode ends, as Brax's trainers expect it (docs/tasks.md):

* **termination**: ``done`` = the task's ``terminated`` (Hopper or Walker2d unhealthy, or a failed
  physics step); Brax's PPO cuts the value to zero there;
* **truncation**: the task's time limit (1,000 of its own steps, ``max_steps`` at another control
  step) is Brax's ``EpisodeWrapper`` with ``episode_length = max_steps`` (pass
  :attr:`BraxTask.max_steps` to ``wrap_for_training``): at that step it sets ``done`` = 1 and
  ``info["truncation"]`` = 1 unless the episode terminated on the same step (Gymnasium's two flags
  both 1: a termination). Brax's PPO bootstraps the value on a truncation. The task's own step
  counter (``info["nmrl"]["steps"]``, never reset by Brax's wrappers) is not used.

**Action.** Brax's actions u (tanh-squashed, in [-1, 1]; clipped to it) map to the task's action
``offset + scale * u``, the actuators' ctrlrange (Gymnasium's action space; [-1, 1] in all three
tasks), as nmrl's PPO maps them (nmrl/learners/ppo_networks.py). ``metrics`` are the task's reward
terms, ``x_velocity``, ``forward_speed`` and ``nonfinite``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from nmrl.adapters.brax_env import INFO_KEY, State, _Base
from nmrl.paper.env import State as _PaperState
from nmrl.tasks.env import Task, TaskConfig

__all__ = ["BraxTask"]


class BraxTask(_Base):
    """One v5 task behind Brax's ``Env`` interface (see the module docstring)."""

    def __init__(self, name: str, control_dt: float | None = None, physics: str = "mjx", threads: int | None = None):
        self.task = Task(name, TaskConfig(control_dt=control_dt, physics=physics, threads=threads, auto_reset=False))
        self.name = name

    @property
    def observation_size(self) -> int:
        return self.task.obs_dim

    @property
    def action_size(self) -> int:
        return self.task.act_dim

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def dt(self) -> float:
        """Seconds per ``step`` (the control step)."""
        return self.task.control_dt

    @property
    def max_steps(self) -> int:
        """The time limit in control steps: Brax's ``episode_length`` for this task."""
        return self.task.max_steps

    @property
    def unwrapped(self) -> "BraxTask":
        return self

    def action(self, u: jax.Array) -> jax.Array:
        """The task's action of Brax's u: ``offset + scale * clip(u, -1, 1)``."""
        return self.task.action_offset + self.task.action_scale * jnp.clip(jnp.asarray(u), -1.0, 1.0)

    def reset(self, rng: jax.Array) -> State:
        """The task's reset (Gymnasium's reset noise, drawn from ``rng``)."""
        return self._to_brax(self.task.reset(rng), info={})

    def step(self, state: State, action: jax.Array) -> State:
        """One control step of the task; ``done`` is its termination (the module docstring)."""
        inner = _PaperState(data=state.pipeline_state, obs=state.obs, reward=state.reward, done=state.done,
                            metrics={}, info=state.info[INFO_KEY])
        return self._to_brax(self.task.step(inner, self.action(action).astype(jnp.float32)), info=state.info)

    @staticmethod
    def _to_brax(s: _PaperState, *, info: dict) -> State:
        info = dict(info)
        info[INFO_KEY] = s.info
        info["stop"] = jnp.zeros((), s.reward.dtype)  # no artificial stop (brax_env.StopIsTruncation)
        return State(pipeline_state=s.data, obs=s.obs, reward=s.reward, done=s.info["terminated"],
                     metrics=dict(s.metrics), info=info)
