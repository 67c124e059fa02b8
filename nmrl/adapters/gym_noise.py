"""nmrl's exploration processes as a Gymnasium action-noise wrapper, in NumPy.

``ExplorationNoise(env, ExplorationSpec("nm-periods", sigma=0.05))`` adds to every action the
agent sends a draw xi_t of one of nmrl's exploration processes (nmrl/explore/spec.py: white, ou,
colored, nm-periods, every parameter in seconds or Hz) at the environment's control step, so that
any Gymnasium learner acts with the paper's temporally correlated noise:

* **The process.** Per action dimension, independently, K latent AR(1) components, each stationary
  N(0, 1): ``z_{k,t} = phi_k z_{k,t-1} + sqrt(1 - phi_k^2) eps_{k,t}`` and ``xi_t = sigma sum_k w_k
  z_{k,t}``, with ``(phi, w, period) = spec.components(control_dt)`` (nmrl/explore/process.py). At a
  period start, every ``period`` steps, z is drawn afresh from N(0, I): with K = 1 this is the
  paper's piecewise AR noise, eq. (4), alpha = phi_1 = exp(-control_dt / corr_time_s) and l =
  round(period_s / control_dt), with covariance (5) inside a period and none across periods. ou is
  the same AR(1) without period starts, white has phi = 0 (the paper's l = 1), colored sums OU
  components fitted to 1/f^beta (nmrl/explore/colored.py). Every xi_t ~ N(0, sigma^2).
  This is the generative form of the process whose conditional form nmrl's JAX sampler draws
  (``nmrl.explore.sample``): the same joint law, drawn here with K normal numbers per dimension.
* **Restart and seeding.** ``reset`` starts a new period (z drawn afresh: the noise of a new trial is
  independent of the last one's, as nmrl restarts it at a trial's start). ``reset(seed=s)`` also
  reseeds the noise's own generator from s, on a stream of its own (``SeedSequence(s,
  spawn_key=(NOISE_STREAM,))``), so that the wrapped environment's draws (the trial stop) stay those
  of the unwrapped one; ``reset()`` without a seed keeps the generator going (the first one is
  seeded from the operating system).
* **Units.** ``sigma`` is in the units of the wrapped environment's action. On the paper's robot
  (nmrl/adapters/gym_env.py) the agent's u maps to the paper's action a = 20 u, so nmrl's
  actor-critic's sigma_a (in units of a) is ``sigma = sigma_a / 20`` here.
* **Clipping.** With ``clip`` (the default) the noisy action is clipped to a bounded Box action
  space, so the environment gets a valid action; ``info["exploration_noise"]`` is the noise xi_t and
  ``info["executed_action"]`` the action the environment got. A learner that wants the executed
  action (an off-policy learner's replay buffer) reads it from there: the agent itself only knows
  the action it sent.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from nmrl.explore.process import NO_RESET
from nmrl.explore.spec import ExplorationSpec

try:
    import gymnasium
    from gymnasium import spaces
except ImportError as e:  # pragma: no cover - depends on the install
    raise ImportError("nmrl.adapters.gym_noise needs Gymnasium: pip install -e '.[dev]' (or pip install "
                      "'gymnasium>=1.0')") from e

__all__ = ["NOISE_STREAM", "ExplorationNoise", "NoiseSampler"]

#: the spawn key of the noise's generator: SeedSequence(seed, spawn_key=(NOISE_STREAM,)) is
#: independent of the environment's own SeedSequence(seed) (Gymnasium's np_random)
NOISE_STREAM = 0x6E6D


class NoiseSampler:
    """The exploration process ``(phi (K,), w (K,), period)`` with marginal std ``sigma`` for
    ``shape``-shaped actions, drawn step by step in float64 (see the module docstring)."""

    def __init__(self, phi: np.ndarray, w: np.ndarray, period: int, sigma: float, shape: tuple[int, ...]):
        self.phi = np.asarray(phi, np.float64)
        self.w = np.asarray(w, np.float64)
        self.innovation = np.sqrt((1.0 - self.phi) * (1.0 + self.phi))  # sqrt(1 - phi^2)
        self.period = int(period)
        self.sigma = float(sigma)
        self.shape = tuple(shape)
        self.z = np.zeros((len(self.phi), math.prod(self.shape)))
        self.i = 0

    @classmethod
    def from_spec(cls, spec: ExplorationSpec, control_dt: float, shape: tuple[int, ...]) -> NoiseSampler:
        """The sampler of ``spec`` at ``control_dt`` seconds (ValueError from the spec's checks)."""
        phi, w, period = spec.components(control_dt)
        return cls(phi, w, period, spec.sigma, shape)

    def restart(self) -> None:
        """The next draw starts a period (z afresh from N(0, I))."""
        self.i = 0

    def draw(self, rng: np.random.Generator) -> np.ndarray:
        """xi_t (``shape``), advancing the process by one step."""
        eps = rng.standard_normal(self.z.shape)
        if self.i == 0:
            self.z = eps
        else:
            self.z = self.phi[:, None] * self.z + self.innovation[:, None] * eps
        self.i = (self.i + 1) % self.period if self.period != NO_RESET else 1
        return (self.sigma * (self.w @ self.z)).reshape(self.shape)


class ExplorationNoise(gymnasium.ActionWrapper, gymnasium.utils.RecordConstructorArgs):
    """Adds nmrl's exploration noise to the agent's action (see the module docstring).

    Args:
        env: a Gymnasium environment with a Box action space.
        spec: the process: an :class:`~nmrl.explore.spec.ExplorationSpec`, or its dict
            (``{"kind": "ou", "sigma": 0.05, "corr_time_s": 0.1}``).
        control_dt: the environment's control step [s]; None reads ``env.unwrapped.dt``.
        clip: clip the noisy action to the action space's bounds.
    """

    def __init__(self, env: gymnasium.Env, spec: ExplorationSpec | Mapping, control_dt: float | None = None,
                 clip: bool = True):
        if not isinstance(env.action_space, spaces.Box):
            raise ValueError(f"action_space={env.action_space!r} is invalid: ExplorationNoise adds noise to a Box "
                             "action space only")
        if isinstance(spec, Mapping):
            spec = ExplorationSpec.from_dict(spec)
        if not isinstance(spec, ExplorationSpec):
            raise ValueError(f"spec={spec!r} is invalid: give an nmrl.explore.ExplorationSpec or its dict")
        if control_dt is None:
            control_dt = getattr(env.unwrapped, "dt", None)
            if control_dt is None:
                raise ValueError("control_dt=None is invalid here: the environment has no dt attribute; give the "
                                 "control step in seconds")
        # recorded for gymnasium.make to rebuild the wrapper from env.spec (the spec as its JSON dict)
        gymnasium.utils.RecordConstructorArgs.__init__(self, spec=spec.to_dict(), control_dt=control_dt, clip=clip)
        gymnasium.ActionWrapper.__init__(self, env)
        self.exploration = spec  #: the ExplorationSpec (``spec`` is Gymnasium's EnvSpec)
        self.control_dt = float(control_dt)
        self.clip = bool(clip)
        self.sampler = NoiseSampler.from_spec(spec, control_dt, env.action_space.shape)
        self._rng: np.random.Generator | None = None
        self.last_noise = np.zeros(env.action_space.shape)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """The environment's reset; the noise restarts, and with ``seed`` its generator is reseeded."""
        if seed is not None:
            self._rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(NOISE_STREAM,)))
        elif self._rng is None:
            self._rng = np.random.default_rng()
        self.sampler.restart()
        return self.env.reset(seed=seed, options=options)

    def action(self, action: Any) -> np.ndarray:
        """``action + xi_t`` (clipped to the space's bounds with ``clip``), in the space's dtype."""
        if self._rng is None:
            self._rng = np.random.default_rng()
        space = self.env.action_space
        self.last_noise = self.sampler.draw(self._rng)
        out = np.asarray(action, np.float64) + self.last_noise
        if self.clip:
            out = np.clip(out, space.low, space.high)
        return out.astype(space.dtype)

    def step(self, action: Any):
        """The environment's step with the noisy action; ``info`` gets ``exploration_noise`` (xi_t)
        and ``executed_action`` (what the environment got)."""
        executed = self.action(action)
        obs, reward, terminated, truncated, info = self.env.step(executed)
        info = dict(info)
        info["exploration_noise"] = self.last_noise.copy()
        info["executed_action"] = executed.copy()
        return obs, reward, terminated, truncated, info
