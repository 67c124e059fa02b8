"""The paper's Half-Cheetah as a ``gymnasium.Env`` on MuJoCo C in float64, for Gymnasium code
(Stable-Baselines3, CleanRL, any loop of ``reset`` and ``step``).

``import nmrl.adapters.gym_env`` registers :data:`ENV_ID` ("nmrl/PaperCheetah-v0"); then
``gymnasium.make("nmrl/PaperCheetah-v0", control_dt=0.02, stop_prob=None)`` builds
:class:`PaperCheetahEnv` (or, with no import first, ``gymnasium.make("nmrl.adapters.gym_env:nmrl/PaperCheetah-v0")``).

It is the robot of :class:`nmrl.paper.env.HalfCheetah` with ``physics="c"``, stepped the same way
but in NumPy and MuJoCo's Python bindings, with no JAX in the step loop:

* **Physics.** The model is models/half_cheetah.xml with a ``jointlimitfrc`` sensor on each
  actuated joint (nmrl/paper/c_plant.py), stepped by ``mujoco.mj_step`` on one ``MjData`` in float64.
  One ``step`` is one control step of ``control_dt / 0.005`` substeps; before every substep the
  torque of Sec. V-A, tau_i = T_i min{max{-1, tau^0_i + a^0_i}, 1} with tau^0_i = 2/pi
  arctan(-2 (omega_i - omega^0_i) - 0.05 d(omega_i)/dt), is computed from the current joint state by
  the C path's own control law (``c_plant.pd_law``). ``mujoco.batch``, which nmrl's C path steps,
  is bit-identical to this loop, so from the same state and action the MuJoCo state here is nmrl's.
* **Action.** The agent's u in the Box [-1, 1]^6 (float32, the normalised space SB3 and CleanRL
  expect) is clipped and mapped to the paper's action a = 20 u, whose control stimulus a^0 = 0.1 a
  = 2u spans the whole torque range whatever the PD term (the mapping of nmrl's Brax adapter and
  PPO, nmrl/adapters/brax_env.py). Action j drives joint I_j = (1, 2, 3, 6, 7, 8)[j].
* **Observation.** The 31 state variables of Table I in the paper's order (float64), from the
  state reached at the end of the step (nmrl/adapters/gym_robot.py).
* **Reward.** The sum of (8)-(14): (8), (11)-(14) at the state s_{t+1} reached, (9) and (10)
  averaged over the substeps; every term is in ``info`` under nmrl's names (``r8_speed`` ...
  ``r14_head``), with ``forward_speed``, ``x`` and the ground contacts of the heel, knee and head.
* **Trial stop: a truncation.** After each step the trial stops with probability ``stop_prob``
  (Sec. V-C: 1/250 at the paper's 0.02 s), drawn from the env's ``np_random`` (seeded by
  ``reset(seed=...)``). The paper's trials "never finish in a terminal state" (Sec. V-D): the stop
  is artificial, so it is ``truncated=True``, never ``terminated``. Left at None, ``stop_prob`` is
  ``control_dt / 5 s``: 1/250 at 0.02 s and the paper's mean trial of 5 s at every control step
  (the conversion of the finer-step study, docs/timescale.md). ``stop_prob=0`` never stops
  (then bound the episode with ``gymnasium.wrappers.TimeLimit`` or ``max_episode_steps``).
* **Failed physics: a termination.** A control step in which MuJoCo warns (e.g. a bad
  acceleration, after which it resets itself), raises, or leaves a non-finite state returns
  ``terminated=True`` with ``info["physics_failed"]`` True, every reward term 0 and the robot back
  in its initial pose, as nmrl's environment flags and resets such a step.
* **Reset.** The initial pose of Sec. V-A at rest, hind paw 0.1 m above the ground, the same at
  every reset (``mj_resetData``; nmrl's ``HalfCheetah.reset(key)`` is the same state for every key,
  whose key only drives the stop rule).

Gymnasium is an optional dependency of nmrl (``pip install -e '.[dev]'``); importing this module
without it raises ImportError naming the install.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import mujoco
import numpy as np

from nmrl.adapters import gym_robot as robot
from nmrl.paper import c_plant
from nmrl.paper.control_step import DELTA_0
from nmrl.paper.env import ACT_DIM, DEFAULT_STOP_PROB, MODEL_PATH, OBS_DIM, REWARD_TERMS, EnvConfig

try:
    import gymnasium
    from gymnasium import spaces
except ImportError as e:  # pragma: no cover - depends on the install
    raise ImportError("nmrl.adapters.gym_env needs Gymnasium: pip install -e '.[dev]' (or pip install "
                      "'gymnasium>=1.0')") from e

__all__ = ["ENV_ID", "ACTION_SCALE", "MAX_CONTROL_DT", "TRIAL_S", "PaperCheetahEnv", "check_control_dt",
           "check_stop_prob", "register"]

#: the id :func:`register` gives the environment (namespace nmrl, version 0)
ENV_ID = "nmrl/PaperCheetah-v0"
#: the agent's u in [-1, 1] -> the paper's action a = ACTION_SCALE * u (a^0 = 0.1 a = 2u), as the
#: Brax adapter and nmrl's PPO map it (nmrl/adapters/brax_env.py, nmrl/learners/ppo_networks.py)
ACTION_SCALE = 20.0
#: the longest control step accepted [s] (the bound of nmrl's own options, nmrl/paper/env.py)
MAX_CONTROL_DT = 1.0
#: the paper's mean trial length [s]: 1/250 stops per 0.02 s step; the default stop_prob is
#: control_dt / TRIAL_S
TRIAL_S = DELTA_0 / DEFAULT_STOP_PROB
_CONTACT_TOL = EnvConfig.contact_tol
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


def _model() -> mujoco.MjModel:
    """The robot with its joint-limit sensors, as nmrl's C path compiles it (nmrl/paper/env.py)."""
    return c_plant.with_limit_sensors(mujoco.MjSpec.from_file(str(MODEL_PATH)))


def _real(name: str, value: Any, allowed: str) -> float:
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ValueError(f"{name}={value!r} is invalid: {allowed}")
    return float(value)


def check_control_dt(control_dt: Any, timestep: float) -> int:
    """The number of MuJoCo substeps of ``control_dt`` seconds: a finite number in (0, 1] s that is a
    whole multiple of the physics ``timestep`` (ValueError naming the value and what is allowed)."""
    allowed = (f"the control step must be a number of seconds in (0, {MAX_CONTROL_DT:g}] that is a whole "
               f"multiple of the physics timestep {timestep:g} s (the paper's is {DELTA_0:g})")
    dt = _real("control_dt", control_dt, allowed)
    n = dt / timestep
    if not 0 < dt <= MAX_CONTROL_DT or round(n) < 1 or abs(n - round(n)) > 1e-6:
        raise ValueError(f"control_dt={control_dt!r} is invalid: {allowed}")
    return int(round(n))


def check_stop_prob(stop_prob: Any, control_dt: float) -> float:
    """The probability of stopping the trial after a step: ``stop_prob`` in [0, 1), or None for
    ``control_dt / TRIAL_S`` (ValueError naming the value and what is allowed)."""
    if stop_prob is None:
        return control_dt / TRIAL_S
    allowed = (f"stop_prob must be a probability per control step in [0, 1), or None for control_dt / {TRIAL_S:g} s "
               f"(the paper's 1/250 at {DELTA_0:g} s)")
    p = _real("stop_prob", stop_prob, allowed)
    if not 0.0 <= p < 1.0:
        raise ValueError(f"stop_prob={stop_prob!r} is invalid: {allowed}")
    return p


class PaperCheetahEnv(gymnasium.Env):
    """The paper's Half-Cheetah for Gymnasium; see the module docstring.

    Args:
        control_dt: the control step [s], a multiple of the physics timestep 0.005 s in (0, 1]
            (the paper's 0.02).
        stop_prob: the probability of stopping (truncating) the trial after each step, in [0, 1);
            None: ``control_dt / 5 s`` (1/250 at 0.02 s).
        render_mode: only None (the environment does not render).
    """

    metadata = {"render_modes": []}
    reward_terms = REWARD_TERMS

    def __init__(self, control_dt: float = DELTA_0, stop_prob: float | None = None, render_mode: str | None = None):
        if render_mode is not None:
            raise ValueError(f"render_mode={render_mode!r} is invalid: this environment does not render (use None)")
        self.model = _model()
        self.n_substeps = check_control_dt(control_dt, float(self.model.opt.timestep))
        self.control_dt = float(control_dt)
        self.stop_prob = check_stop_prob(stop_prob, self.control_dt)
        self.render_mode = None
        self.data = mujoco.MjData(self.model)
        self._nstate = int(mujoco.mj_stateSize(self.model, _STATE))
        self.action_space = spaces.Box(-1.0, 1.0, (ACT_DIM,), np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float64)

    @property
    def dt(self) -> float:
        """Seconds per ``step`` (Gymnasium's MuJoCo environments name it so)."""
        return self.control_dt

    # ------------------------------------------------------------------ Gymnasium's API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """The initial pose of Sec. V-A at rest; ``seed`` seeds the stop rule's generator."""
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        obs, info, _ = self._observe()
        info.update({k: 0.0 for k in REWARD_TERMS})
        info["physics_failed"] = False
        return obs, info

    def step(self, action: Any):
        """One control step with a = 20 clip(u, -1, 1); returns (obs, reward, terminated, truncated, info)."""
        u = np.asarray(action, np.float64)
        if u.shape != (ACT_DIM,):
            raise ValueError(f"action must have shape ({ACT_DIM},), got shape {u.shape}")
        a = ACTION_SCALE * np.clip(u, -1.0, 1.0)
        excess, tau_w, ok = self._advance(a)
        if not ok:  # as nmrl: the state is replaced by the initial one, the step earns nothing
            mujoco.mj_resetData(self.model, self.data)
        obs, info, (p, v) = self._observe()
        if ok:
            terms = robot.state_rewards(p, v, _CONTACT_TOL)
            terms.update(robot.torque_rewards(excess, tau_w))
        else:
            terms = dict.fromkeys(REWARD_TERMS, 0.0)
        reward = float(sum(terms[k] for k in REWARD_TERMS))
        info.update({k: terms[k] for k in REWARD_TERMS})
        info["physics_failed"] = not ok
        truncated = bool(self.np_random.random() < self.stop_prob) and ok
        return obs, reward, not ok, truncated, info

    def mujoco_state(self) -> np.ndarray:
        """MuJoCo's integration state (``mj_getState``, mjSTATE_INTEGRATION) as float64: what nmrl's
        C path carries between steps (``nmrl.physics.mujoco_c.from_bits`` of its state)."""
        s = np.empty(self._nstate)
        mujoco.mj_getState(self.model, self.data, s, _STATE)
        return s

    # ------------------------------------------------------------------ helpers
    def _advance(self, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """The substeps of one control step with the action held: (excess over saturation (9),
        joint-limit force tau^w (10), ok), per substep and actuated joint in actuator order."""
        m, d = self.model, self.data
        d.warning.number[:] = 0
        n = self.n_substeps
        excess = np.zeros((n, ACT_DIM))
        tau_w = np.zeros((n, ACT_DIM))
        ok = True
        a = a[None]
        for k in range(n):
            ctrl, law = c_plant.pd_law(d.qpos[None], d.qvel[None], a)
            d.ctrl[:] = ctrl[0]
            try:
                mujoco.mj_step(m, d)
            except mujoco.FatalError:  # pragma: no cover - MuJoCo's errors are rare
                ok = False
                break
            excess[k] = law[0]
            tau_w[k] = d.sensordata  # computed at the state the substep started from (mj_step)
        ok = ok and not d.warning.number.any() and bool(np.all(np.isfinite(self.mujoco_state())))
        return excess, tau_w, ok

    def _observe(self) -> tuple[np.ndarray, dict[str, Any], tuple[np.ndarray, np.ndarray]]:
        """(Table I's observation, the metrics beside the reward, (joint positions, velocities))."""
        p, v, phi, dphi = robot.kinematics(self.data.qpos, self.data.qvel)
        return robot.observation(p, v, phi, dphi, _CONTACT_TOL), robot.extra_metrics(p, v, _CONTACT_TOL), (p, v)


def register(env_id: str = ENV_ID) -> None:
    """Register :class:`PaperCheetahEnv` with Gymnasium under ``env_id`` (idempotent: an id already
    registered by this module is left as it is). ``gymnasium.make(env_id, control_dt=...,
    stop_prob=...)`` passes both to the constructor, which checks them."""
    if env_id in gymnasium.registry:
        return
    gymnasium.register(id=env_id, entry_point=f"{__name__}:PaperCheetahEnv")


register()
