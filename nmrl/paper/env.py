"""The paper's Half-Cheetah (Sec. V-A, V-B) as a batched MJX environment.

``env = HalfCheetah(); state = env.reset(key); state = env.step(state, action)``; both are pure
functions of pytrees and work under ``jax.jit`` and ``jax.vmap`` (Brax-style).

One ``step`` is one control step (0.02 s by default) made of ``control_dt / timestep`` MuJoCo
substeps. Within it the network's action ``a`` (6,) gives the control stimuli a^0_i = 0.1 a_j
(Sec. V-C) held constant, and in every substep the torque of Sec. V-A,

    tau^0_i = 2/pi * arctan(-2 (omega_i - omega^0_i) - 0.05 d(omega_i)/dt),
    tau_i   = T_i * min{max{-1, tau^0_i + a^0_i}, 1},

is recomputed from the current joint state (the "spontaneous" PD torque is part of the plant).

The observation is the 31 variables of Table I in the paper's order (``obs[k-1] = s_{t,k}``) and
the reward is the sum of (8)-(14); every term is in ``state.metrics`` (the equations as functions of
the joint state: nmrl/paper/robot.py). The choices the paper leaves open are listed in
docs/model.md; in short:

* s_{t,2} is ``dy_0/dt / 0.3`` (the dot was lost in the text: s_1 already is y_0, and s_8..s_10 of the
  front paw read (y_9 - 0.1)/0.1, dy_9/dt / 0.3, [y_9 = 0]).
* ``[y_i = 0]`` ("the paw stands on the ground") is ``y_i <= contact_tol`` (5 mm); y_i is the height of
  the joint's centre, and the floor is placed one contact-sphere radius below y = 0.
* (8), (11)-(14) are evaluated at the state s_{t+1} reached at the end of the control step
  (r_t = r(a_t, s_{t+1}), Sec. II); (9) and (10) are averaged over the substeps of the step.
* tau^w in (10) is the joint-limit constraint force MuJoCo's solver applies to the joint; the
  per-instant term min{|tau^w_i|, 50} is averaged over the substeps, like (9).

Physics (``EnvConfig.physics``): ``"mjx"`` steps the model with MJX (float32, any device);
``"c"`` steps it with MuJoCo C (float64) through nmrl/physics/mujoco_c.py, the PD torque computed in
NumPy before each substep and tau^w read from ``jointlimitfrc`` sensors (nmrl/paper/c_plant.py). On
both, the observation and the reward are computed in JAX from the step's qpos/qvel and the substeps'
reports, and a failed step (non-finite state; on C also a MuJoCo warning or error) stops the trial.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from nmrl.paper import _mjx as mjx  # quiet import (see nmrl/__init__.py)

from nmrl.paper import c_plant
from nmrl.paper.control_step import DEFAULT_STOP_PROB, DELTA_0
from nmrl.paper.robot import kinematics, observation, pd_torque, state_rewards
from nmrl.physics import mujoco_c

MODEL_PATH = pathlib.Path(__file__).resolve().parents[2] / "models" / "half_cheetah.xml"
OBS_DIM = 31
ACT_DIM = 6
#: Actuator order of the MJCF (= qpos order of the hinges) mapped to the action index j - 1.
_ACT_OF_CTRL = c_plant.ACT_OF_CTRL
REWARD_TERMS = ("r8_speed", "r9_torque", "r10_limit", "r11_lift", "r12_heel", "r13_knee", "r14_head")


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Environment options. Defaults are the paper's (Sec. V-C) and docs/model.md's physics."""

    control_dt: float = DELTA_0  #: control step delta [s] (the paper's, nmrl/paper/control_step.py)
    stop_prob: float = DEFAULT_STOP_PROB  #: probability of stopping the trial after each step
    #: mean trial length [s]; when set, the stop probability per step is control_dt / trial_s, so a
    #: trial lasts trial_s seconds on average at every control step (None: stop_prob as given)
    trial_s: float | None = None
    contact_tol: float = 0.005  #: a joint "stands on the ground" when its height <= this [m]
    timestep: float | None = None  #: physics timestep [s]; None = the MJCF's (0.005)
    solver_iterations: int | None = None  #: None = the MJCF's (4)
    ls_iterations: int | None = None  #: None = the MJCF's (4)
    auto_reset: bool = True  #: reset a stopped trial inside ``step`` (batched training)
    #: "mjx" (MJX, any device) or "c" (MuJoCo C on the CPU): one of nmrl.physics.PHYSICS, checked where
    #: a run declares it (nmrl/tasks/__init__.py's ``EnvFields``)
    physics: str = "mjx"
    #: threads of each device's C batch (physics "c"; results are bit-identical at any count);
    #: None: this process's cores divided by its JAX devices
    threads: int | None = None

    def validate(self) -> None:
        if self.threads is not None and not (isinstance(self.threads, int) and self.threads >= 1):
            raise ValueError(f"threads must be an integer >= 1 or None, got {self.threads!r}")
        if not self.control_dt > 0:
            raise ValueError(f"control_dt must be > 0 seconds, got {self.control_dt!r}")
        if not 0.0 <= self.stop_prob < 1.0:
            raise ValueError(f"stop_prob must be in [0, 1), got {self.stop_prob!r}")
        check_trial_s(self.trial_s, self.stop_prob, self.control_dt)
        if not (np.isfinite(self.contact_tol) and self.contact_tol >= 0):
            raise ValueError(f"contact_tol must be a finite number >= 0 metres, got {self.contact_tol!r}")
        if self.timestep is not None and not self.timestep > 0:
            raise ValueError(f"timestep must be > 0 seconds, got {self.timestep!r}")
        for name in ("solver_iterations", "ls_iterations"):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, int) or v < 1):
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")

    @property
    def step_stop_prob(self) -> float:
        """The probability of stopping the trial after a control step (see ``trial_s``)."""
        return self.stop_prob if self.trial_s is None else self.control_dt / self.trial_s




def check_trial_s(trial_s, stop_prob, control_dt) -> None:
    """``trial_s`` None, or a finite time longer than one control step given without a stop_prob of
    its own (ValueError naming the value)."""
    if trial_s is None:
        return
    if isinstance(trial_s, bool) or not isinstance(trial_s, (int, float)) or not np.isfinite(trial_s) \
            or not trial_s > control_dt:
        raise ValueError(f"trial_s={trial_s!r} is invalid: must be a finite time in seconds longer than the "
                         f"control step ({control_dt!r} s)")
    if stop_prob != DEFAULT_STOP_PROB:
        raise ValueError(f"trial_s={trial_s!r} and stop_prob={stop_prob!r}: give the stop rule as one of them")


@struct.dataclass
class CData:
    """The physics state on the C path: MuJoCo's integration state as float64 bits, and its qpos/qvel
    in float32 for the observation (what ``State.data`` is on the MJX path's ``mjx.Data``)."""

    state: jax.Array  #: (2 nstate,) uint32 (nmrl/physics/mujoco_c.py)
    qpos: jax.Array
    qvel: jax.Array


@struct.dataclass
class State:
    """Immutable environment state (a pytree)."""

    data: mjx.Data | CData
    obs: jax.Array  #: (31,) Table I
    reward: jax.Array  #: () sum of (8)-(14) for the step that produced this state
    done: jax.Array  #: () 1.0 if the trial was stopped after this step (or the physics failed)
    metrics: dict[str, jax.Array]
    info: dict[str, Any]


class HalfCheetah:
    """The paper's Half-Cheetah stepped by MJX. See the module docstring."""

    obs_dim = OBS_DIM
    act_dim = ACT_DIM
    reward_terms = REWARD_TERMS

    def __init__(self, config: EnvConfig | None = None, model_path: str | os.PathLike = MODEL_PATH):
        self.config = config = config or EnvConfig()
        config.validate()
        mj = mujoco.MjModel.from_xml_path(str(model_path))
        self._set_options(mj)
        n_sub = config.control_dt / mj.opt.timestep
        if abs(n_sub - round(n_sub)) > 1e-6 or round(n_sub) < 1:
            raise ValueError(
                f"control_dt={config.control_dt} must be a positive multiple of the physics timestep "
                f"{mj.opt.timestep}"
            )
        self.n_substeps = int(round(n_sub))
        self.mj_model = mj
        self.c = None
        if config.physics == "c":
            cm = c_plant.with_limit_sensors(mujoco.MjSpec.from_file(str(model_path)))
            self._set_options(cm)
            self.c = mujoco_c.CPhysics(c_plant.plant(cm, self.n_substeps),
                                       threads=config.threads or mujoco_c.threads_per_device())
            s0 = self.c.initial_state()
            q0, v0 = self.c.split(s0)
            self._data0 = CData(state=jnp.asarray(mujoco_c.to_bits(s0)), qpos=jnp.asarray(q0, jnp.float32),
                                qvel=jnp.asarray(v0, jnp.float32))
            return
        # This process's own device: MJX's default, jax.devices()[0], belongs to process 0 in a
        # multi-process run (nmrl/runs/distributed.py); in a 1-process run the two are the same.
        dev = jax.local_devices()[0]
        self.model = mjx.put_model(mj, device=dev)
        d = mjx.make_data(self.model, device=dev)
        d = jax.jit(mjx.forward)(self.model, d)
        # Rows of the constraint Jacobian that are joint limits (static layout in MJX).
        efc_type = np.asarray(d._impl.efc_type)
        self._limit_rows = np.nonzero(efc_type == int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT))[0]
        self._data0 = d

    def _set_options(self, mj: mujoco.MjModel) -> None:
        cfg = self.config
        if cfg.timestep is not None:
            mj.opt.timestep = cfg.timestep
        if cfg.solver_iterations is not None:
            mj.opt.iterations = cfg.solver_iterations
        if cfg.ls_iterations is not None:
            mj.opt.ls_iterations = cfg.ls_iterations

    # ------------------------------------------------------------------ reset
    def reset(self, key: jax.Array) -> State:
        """Initial pose of Sec. V-A, hind paw 0.1 m above the ground, at rest."""
        data = self._data0
        p, v, phi, dphi = kinematics(data.qpos, data.qvel)
        zero = jnp.zeros((), data.qpos.dtype)
        metrics = {k: zero for k in REWARD_TERMS}
        metrics.update(self._extra_metrics(p, v, jnp.zeros((), bool)))
        obs = observation(p, v, phi, dphi, self.config.contact_tol)
        info = {"key": key, "steps": jnp.zeros((), jnp.int32), "terminal_obs": obs}
        return State(data=data, obs=obs, reward=zero, done=zero, metrics=metrics, info=info)

    # ------------------------------------------------------------------- step
    def step(self, state: State, action: jax.Array) -> State:
        """One control step; with ``auto_reset`` a stopped trial restarts (``done`` flags it)."""
        action = self._check_action(action)
        cfg = self.config
        a0 = 0.1 * action[_ACT_OF_CTRL]

        if self.c is None:
            def substep(carry, _):
                data = carry
                tau, pre = pd_torque(data.qpos, data.qvel, a0)
                data = mjx.step(self.model, data.replace(ctrl=tau))
                tau_w = self._limit_torque(data)
                return data, (jnp.maximum(jnp.abs(pre) - 1.0, 0.0), tau_w)

            data, (over, tau_w) = jax.lax.scan(substep, state.data, None, length=self.n_substeps)
            ok = True
        else:
            adv = self.c.advance(state.data.state, action)
            data = CData(state=adv.state, qpos=adv.qpos, qvel=adv.qvel)
            over, tau_w, ok = adv.reports[:, :ACT_DIM], adv.reports[:, ACT_DIM:], adv.ok
        finite = ok & jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        # Non-finite physics is flagged and replaced by the reset state (it forces a trial stop).
        data = jax.tree.map(lambda a, b: jnp.where(finite, a, b), data, self._data0)
        p, v, phi, dphi = kinematics(data.qpos, data.qvel)
        terms = state_rewards(p, v, cfg.contact_tol)
        terms["r9_torque"] = -0.05 * jnp.sum(jnp.mean(over, axis=0))
        terms["r10_limit"] = -0.1 * jnp.sum(jnp.mean(jnp.minimum(jnp.abs(tau_w), 50.0), axis=0))
        terms = {k: jnp.where(finite, terms[k], 0.0) for k in REWARD_TERMS}
        reward = sum(terms[k] for k in REWARD_TERMS)  # the learner scales it (TrainConfig.reward_scale)
        obs = observation(p, v, phi, dphi, cfg.contact_tol)
        key, k_stop = jax.random.split(state.info["key"])
        stopped = (jax.random.uniform(k_stop) < cfg.step_stop_prob) | ~finite
        metrics = dict(terms)
        metrics.update(self._extra_metrics(p, v, ~finite))
        info = {"key": key, "steps": state.info["steps"] + 1, "terminal_obs": obs}
        new = State(data=data, obs=obs, reward=reward, done=stopped.astype(reward.dtype), metrics=metrics,
                    info=info)
        if cfg.auto_reset:
            fresh = self.reset(key)
            new = new.replace(
                data=jax.tree.map(lambda a, b: jnp.where(stopped, a, b), fresh.data, data),
                obs=jnp.where(stopped, fresh.obs, obs),
                info={**info, "steps": jnp.where(stopped, 0, info["steps"])},
            )
        return new

    # ---------------------------------------------------------------- perturbed start
    def perturb(self, state: State, key: jax.Array, scale: float) -> State:
        """``state`` with every hinge angle moved by U(-scale, scale) rad and every hinge velocity by
        scale * N(0, 1) rad/s (Gymnasium's reset noise, on the joints only: the trunk keeps its pose),
        its observation recomputed: a start that differs between rollouts of a deterministic policy."""
        k_q, k_v = jax.random.split(key)
        nq, nv = self.mj_model.nq, self.mj_model.nv
        dq = jnp.zeros(nq).at[3:].set(jax.random.uniform(k_q, (nq - 3,), minval=-scale, maxval=scale))
        dv = jnp.zeros(nv).at[3:].set(scale * jax.random.normal(k_v, (nv - 3,)))
        if self.c is None:
            data = state.data.replace(qpos=state.data.qpos + dq, qvel=state.data.qvel + dv)
        else:
            bits, qpos, qvel = self.c.shift(state.data.state, dq, dv)
            data = CData(state=bits, qpos=qpos, qvel=qvel)
        p, v, phi, dphi = kinematics(data.qpos, data.qvel)
        metrics = {**state.metrics, **self._extra_metrics(p, v, jnp.zeros((), bool))}
        obs = observation(p, v, phi, dphi, self.config.contact_tol)
        return state.replace(data=data, obs=obs, metrics=metrics, info={**state.info, "terminal_obs": obs})

    # --------------------------------------------------------------- helpers
    def _limit_torque(self, data: mjx.Data) -> jax.Array:
        """tau^w: the joint-limit constraint force on each actuated joint (actuator order)."""
        rows = self._limit_rows
        J = data._impl.efc_J[rows]
        f = data._impl.efc_force[rows]
        return (J.T @ f)[3:]

    def _extra_metrics(self, p, v, nonfinite) -> dict[str, jax.Array]:
        y = p[:, 1]
        tol = self.config.contact_tol
        dt = p.dtype
        return {
            "forward_speed": 0.5 * (v[3, 0] + v[4, 0]),
            "x": 0.5 * (p[3, 0] + p[4, 0]),
            "heel_ground": (y[1] <= tol).astype(dt),
            "knee_ground": (y[2] <= tol).astype(dt),
            "head_ground": (y[5] <= tol).astype(dt),
            "nonfinite": nonfinite.astype(dt),
        }

    @staticmethod
    def _check_action(action: Any) -> jax.Array:
        action = jnp.asarray(action)
        if action.shape != (ACT_DIM,):
            raise ValueError(
                f"action must have shape ({ACT_DIM},) (vmap over a batch), got shape {action.shape}"
            )
        if not jnp.issubdtype(action.dtype, jnp.floating):
            raise TypeError(f"action must be a floating-point array, got dtype {action.dtype}")
        return action
