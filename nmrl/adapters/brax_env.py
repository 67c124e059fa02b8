"""The paper's Half-Cheetah (nmrl.paper.env) as a Brax environment, for the ecosystem's trainers.

``BraxHalfCheetah`` satisfies ``brax.envs.Env``: ``observation_size`` (31, Table I),
``action_size`` (6), ``backend`` ("mjx"), ``reset(rng)`` and ``step(state, action)`` on a Brax
``State(pipeline_state, obs, reward, done, metrics, info)``. The physics, the "spontaneous" PD
torque, the joint strengths and the reward (8)-(14) are those of :class:`nmrl.paper.env.HalfCheetah`
(one ``step`` = one 0.02 s control step), which this class wraps with ``auto_reset=False``:
resetting a stopped trial is left to Brax's ``AutoResetWrapper``.

Two choices the paper does not make for a trainer with a bounded action space:

* **Action scale.** Brax's trainers emit actions in [-1, 1] (a tanh-squashed Gaussian). The paper's
  action a enters the torque as a^0 = 0.1 a inside min{max{-1, tau^0 + a^0}, 1} with tau^0 in
  (-1, 1) (Sec. V-A), so a^0 in [-2, 2] already reaches every torque the clip allows, whatever
  the PD term. The adapter maps u in [-1, 1] to a = ``ACTION_SCALE`` u = 20 u (a^0 = 2u): full
  control authority and nothing beyond it. u outside [-1, 1] is clipped.
* **The stop rule is a truncation.** After each step the trial is stopped with probability 1/250
  (Sec. V-C), and "the trials never finish in a terminal state" (Sec. V-D): the stop is artificial.
  The adapter reports it as ``done`` = 1 with ``info["stop"]`` = 1; :func:`wrap_for_training`
  (Brax's own ``envs.training.wrap``: VmapWrapper, EpisodeWrapper, AutoResetWrapper) then marks
  such a step as ``info["truncation"]`` = 1 (and ``"time_out"``), which Brax's PPO treats as a
  time limit (the value is not cut to zero there), not as a termination. A step whose physics
  failed (non-finite, ``info["stop"]`` = 0) stays a termination.

``metrics`` are every reward term of (8)-(14), ``forward_speed`` etc. of nmrl.paper.env, plus
``reward_per_step`` and ``forward_speed_per_step``: Brax's EpisodeWrapper sums metrics over an
episode and its training logger divides ``*_per_step`` sums by the episode length, so Brax reports
the average reward per step of the finished trials (the paper's measure, per trial).

Brax is optional (``pip install -e '.[brax]'``). Without it, this module still works: ``State`` is
then a local flax dataclass with Brax's fields and :class:`BraxHalfCheetah` a plain class with the
same methods; :func:`wrap_for_training` needs Brax.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from nmrl.paper.env import ACT_DIM, OBS_DIM, EnvConfig, HalfCheetah
from nmrl.paper.env import State as _PaperState

try:  # optional dependency
    from brax.envs import base as _brax_base
    from brax.envs.wrappers import training as _brax_training

    HAVE_BRAX = True
except ImportError:  # pragma: no cover - depends on the install
    _brax_base = None
    _brax_training = None
    HAVE_BRAX = False

__all__ = ["ACTION_SCALE", "HAVE_BRAX", "BraxHalfCheetah", "State", "wrap_for_training",
           "require_brax"]

#: Brax action u in [-1, 1] -> the paper's action a = ACTION_SCALE * u (a^0 = 0.1 a = 2u).
ACTION_SCALE = 20.0
#: Key of this adapter's own per-environment state in ``State.info`` (PRNG key of the stop rule).
INFO_KEY = "nmrl"

if HAVE_BRAX:
    State = _brax_base.State
    _Base = _brax_base.Env
else:
    @struct.dataclass
    class State:  # the fields of brax.envs.base.State
        pipeline_state: Any
        obs: jax.Array
        reward: jax.Array
        done: jax.Array
        metrics: dict = struct.field(default_factory=dict)
        info: dict = struct.field(default_factory=dict)

    _Base = object


def require_brax() -> None:
    """Raise ImportError with the install command if Brax is not installed; else make sure the
    pinned JAX has what Brax's trainers call (:func:`jax_compat`)."""
    if not HAVE_BRAX:
        raise ImportError("Brax is not installed; it is an optional extra: pip install -e '.[brax]'")
    jax_compat()


def jax_compat() -> None:
    """Brax 0.14.2's trainers call ``jax.device_put_replicated`` (brax/training/agents/ppo/train.py,
    brax/training/pmap.py), a name the pinned JAX 0.10.2 no longer exports: accessing it raises
    ``AttributeError: jax.device_put_replicated is deprecated; use jax.device_put instead``. JAX
    0.10.2 still has the function itself (``jax._src.api.device_put_replicated``); this puts it
    back under its public name, in this process only, when (and only when) it is missing. With a
    JAX that still exports the name (or a Brax that no longer uses it) nothing is changed."""
    try:
        jax.device_put_replicated  # noqa: B018
    except AttributeError:
        from jax._src import api

        jax.device_put_replicated = api.device_put_replicated


class BraxHalfCheetah(_Base):
    """The paper's Half-Cheetah behind Brax's ``Env`` interface (see the module docstring)."""

    def __init__(self, config: EnvConfig | None = None):
        cfg = dataclasses.replace(config or EnvConfig(), auto_reset=False)
        self.paper = HalfCheetah(cfg)
        self.config = cfg

    # ----------------------------------------------------------------- Brax's interface
    @property
    def observation_size(self) -> int:
        return OBS_DIM

    @property
    def action_size(self) -> int:
        return ACT_DIM

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def dt(self) -> float:
        """Seconds per ``step`` (the control step delta)."""
        return self.config.control_dt

    @property
    def unwrapped(self) -> "BraxHalfCheetah":
        return self

    def reset(self, rng: jax.Array) -> State:
        """The paper's initial pose (hind paw 0.1 m above the ground, at rest)."""
        return self._to_brax(self.paper.reset(rng), stop=jnp.zeros(()))

    def step(self, state: State, action: jax.Array) -> State:
        """One 0.02 s control step with the paper's action a = ACTION_SCALE * clip(u, -1, 1)."""
        u = jnp.clip(jnp.asarray(action), -1.0, 1.0)
        inner = _PaperState(data=state.pipeline_state, obs=state.obs, reward=state.reward, done=state.done,
                            metrics={}, info=state.info[INFO_KEY])
        new = self.paper.step(inner, ACTION_SCALE * u)
        # done: the stop rule or failed physics; ``stop``: the stop rule alone (a truncation)
        stop = new.done * (1.0 - new.metrics["nonfinite"])
        return self._to_brax(new, stop=stop, info=state.info)

    # ------------------------------------------------------------------------ helpers
    @staticmethod
    def _to_brax(s: _PaperState, *, stop: jax.Array, info: dict | None = None) -> State:
        metrics = dict(s.metrics)
        metrics["reward_per_step"] = s.reward
        metrics["forward_speed_per_step"] = s.metrics["forward_speed"]
        info = dict(info or {})
        info[INFO_KEY] = s.info
        info["stop"] = jnp.asarray(stop, s.reward.dtype)
        return State(pipeline_state=s.data, obs=s.obs, reward=s.reward, done=s.done, metrics=metrics,
                     info=info)


if HAVE_BRAX:
    class StopIsTruncation(_brax_training.Wrapper):
        """Marks the paper's artificial trial stop (``info["stop"]``) as a truncation for Brax's trainers:
        ``info["truncation"]`` and ``info["time_out"]`` are set to 1 on such a step (Sec. V-D)."""

        def reset(self, rng: jax.Array) -> State:
            state = self.env.reset(rng)
            state.info["time_out"] = jnp.zeros_like(state.done)
            return state

        def step(self, state: State, action: jax.Array) -> State:
            state = self.env.step(state, action)
            stop = state.info["stop"]
            state.info["truncation"] = jnp.maximum(state.info["truncation"], stop)
            state.info["time_out"] = state.info["truncation"]
            return state


    class Tally(_brax_training.Wrapper):
        """Reports the learning's own average reward per step to the host, exactly: every ``every``
        steps of the batch it calls ``sink(reward_sum, forward_speed_sum, stops, steps)`` (numpy
        values summed over its environments and those steps; one call per device) through
        ``jax.debug.callback``, and starts its sums anew. ``sink`` must not call JAX (it runs while
        the devices wait for it). Brax's own training logger is not used for this: it keeps only the
        last 100 finished episodes and calls jax.numpy inside its callback, which deadlocked here
        with 2 CPU devices at full size."""

        def __init__(self, env: Any, sink: Any, every: int = 256):
            super().__init__(env)
            self.sink, self.every = sink, int(every)

        def reset(self, rng: jax.Array) -> State:
            state = self.env.reset(rng)
            z = jnp.zeros_like(state.reward)  # per environment: the wrappers below vmap every leaf
            state.info["tally"] = {"reward": z, "speed": z, "stops": z, "n": jnp.zeros(z.shape, jnp.int32)}
            return state

        def step(self, state: State, action: jax.Array) -> State:
            t = state.info["tally"]
            state = self.env.step(state, action)
            t = {"reward": t["reward"] + state.reward, "speed": t["speed"] + state.metrics["forward_speed"],
                 "stops": t["stops"] + state.done, "n": t["n"] + 1}
            steps = jnp.sum(t["n"])
            flush = jnp.max(t["n"]) >= self.every  # every environment has stepped as often
            jax.lax.cond(flush, lambda a: jax.debug.callback(self.sink, *a), lambda a: None,
                         (jnp.sum(t["reward"]), jnp.sum(t["speed"]), jnp.sum(t["stops"]), steps))
            state.info["tally"] = jax.tree.map(lambda x: jnp.where(flush, jnp.zeros_like(x), x), t)
            return state


def wrap_for_training(env: Any, episode_length: int = 1000, action_repeat: int = 1,
                      randomization_fn: Any = None, *, tally: Any = None, tally_every: int = 256) -> Any:
    """Brax's training wrappers (``brax.envs.training.wrap``: Vmap, Episode, AutoReset) with the
    paper's stop rule marked as a truncation (:class:`StopIsTruncation`), and, with ``tally`` (a
    host function), the exact training reward reported to it (:class:`Tally`). Pass it to Brax's
    trainers as ``wrap_env_fn``; ``episode_length`` is then only a cap (trials end by the stop rule,
    ~250 steps on average)."""
    require_brax()
    wrapped = StopIsTruncation(_brax_training.wrap(env, episode_length=episode_length, action_repeat=action_repeat,
                                                   randomization_fn=randomization_fn))
    return wrapped if tally is None else Tally(wrapped, tally, tally_every)
