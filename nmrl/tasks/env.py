"""Gymnasium's v5 HalfCheetah, Hopper and Walker2d (nmrl/tasks/gym_v5.py) as batched environments
with the paper's environment interface (nmrl/paper/env.py).

``env = Task("hopper-v5"); state = env.reset(key); state = env.step(state, action)``: pure functions
of pytrees, under ``jax.jit`` and ``jax.vmap``; ``obs_dim``, ``act_dim``; the state is
:class:`nmrl.paper.env.State` (obs, reward, done, metrics, info). One ``step`` is Gymnasium's
``MujocoEnv.step`` (``gymnasium/envs/mujoco/<task>_v5.py``, wrapped by ``TimeLimit``):

* ``ctrl = clip(action, ctrlrange)`` held for the control step's ``n_substeps`` MuJoCo steps (MuJoCo
  clamps Gymnasium's unclipped ``data.ctrl`` to the same range, so the dynamics are the same);
* ``x_velocity = (x_after - x_before) / control_dt`` with x = ``qpos[0]``; the reward
  ``forward_reward_weight * x_velocity + healthy_reward * healthy - ctrl_cost_weight * |action|^2``
  (the unclipped action, as Gymnasium), each term in ``metrics`` ("reward_forward", "reward_ctrl",
  "reward_survive");
* healthy (Hopper, Walker2d) is read after the step; ``terminated = not healthy`` (or a failed
  physics step: non-finite state, on C also a MuJoCo warning); ``truncated`` when the episode reaches
  ``max_steps``. ``info["terminated"]`` and ``info["truncated"]`` are Gymnasium's two flags (both can
  be 1 at the last step); ``done = terminated or truncated``. A learner bootstraps on
  ``truncated and not terminated``.

**The control step in seconds.** ``TaskConfig.control_dt`` None is the task's own step (frame skip
x the MJCF's timestep: 0.05 s HalfCheetah, 0.008 s Hopper, Walker2d); another multiple of the
timestep changes the frame skip and keeps the timestep. The rewards are rates: Gymnasium's per-step
reward is taken as the rate ``r / dt0`` per second (dt0 the task's own step) and integrated over
the control step, so the reward of one step is ``r * control_dt / dt0`` (x_velocity is itself a rate
and is not rescaled inside). At dt0 it is Gymnasium's reward exactly; at any step the return of a
second is the same quantity, and the time limit stays ``1000 * dt0`` seconds
(``max_steps = round(1000 dt0 / control_dt)``).

**Physics** (``TaskConfig.physics``): ``"mjx"`` steps the model with MJX (float32); ``"c"`` with
MuJoCo C through nmrl/physics/mujoco_c.py's generic boundary (float64, the same ``mj_step`` as
Gymnasium's), the law ``ctrl = clip(action)`` per substep. On C the reward and the healthy rule read
``qpos``/``qvel`` from the float64 state bits as float32 pairs (nmrl/tasks/doubles.py), so they are
Gymnasium's float64 decisions; the observation is Gymnasium's rounded to float32.

**Reset**: Gymnasium's ``reset_model``: ``qpos0 + U(-s, s)`` and ``qvel`` from ``U(-s, s)``
(HalfCheetah: ``s N(0, 1)``), drawn from ``key``. :meth:`Task.state_at` builds the state of given
float64 ``qpos``/``qvel`` on the host (a Gymnasium environment's, for the tests).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from nmrl.paper import _mjx as mjx  # quiet import (see nmrl/__init__.py)
from nmrl.paper.env import CData, State
from nmrl.physics import mujoco_c
import nmrl.tasks.doubles as doubles  # (not ``from nmrl.tasks``: the package imports this module)
from nmrl.tasks.gym_v5 import TASKS, TaskSpec, load_model, model_path


@dataclasses.dataclass(frozen=True)
class TaskConfig:
    """The options of a task run (the task's own options are Gymnasium's defaults, not options)."""

    control_dt: float | None = None  #: control step [s]; None: the task's own (frame skip x timestep)
    physics: str = "mjx"  #: "mjx" or "c" (nmrl.physics.PHYSICS; checked where a run declares it)
    threads: int | None = None  #: threads of each device's C batch (None: cores / devices)
    auto_reset: bool = True  #: restart an ended episode inside ``step``

    def validate(self) -> None:
        if self.threads is not None and not (isinstance(self.threads, int) and self.threads >= 1):
            raise ValueError(f"threads must be an integer >= 1 or None, got {self.threads!r}")
        if self.control_dt is not None and not (isinstance(self.control_dt, (int, float))
                                                and np.isfinite(self.control_dt) and self.control_dt > 0):
            raise ValueError(f"control_dt={self.control_dt!r} is invalid: must be a finite time > 0 s")


def control_steps(spec: TaskSpec, control_dt: float | None) -> int:
    """MuJoCo steps per control step of ``control_dt`` (None: the task's frame skip); ValueError in
    one line unless it is a positive multiple of the task's physics timestep."""
    if control_dt is None:
        return spec.frame_skip
    n = control_dt / spec.timestep
    if abs(n - round(n)) > 1e-6 or round(n) < 1:
        raise ValueError(f"control_dt={control_dt!r} is invalid: must be a positive multiple of "
                         f"{spec.gym_id}'s physics timestep {spec.timestep:g} s")
    return int(round(n))


def _law(lo: np.ndarray, hi: np.ndarray):
    """The C plant's per-substep law: ctrl = the action clipped to ctrlrange; it reports nothing
    (the reward reads x before and after from the float64 state, not from float32 reports)."""
    def control(qpos, qvel, action):
        return np.clip(action, lo, hi), np.zeros((len(action), 0))
    return control


class Task:
    """One v5 task (a name of :data:`nmrl.tasks.gym_v5.TASKS`). See the module docstring."""

    def __init__(self, name: str, config: TaskConfig | None = None):
        if name not in TASKS:
            raise ValueError(f"env={name!r} is unknown: choose one of {', '.join(TASKS)}")
        self.name = name
        self.spec: TaskSpec = TASKS[name]
        self.config = config = config or TaskConfig()
        config.validate()
        path = model_path(self.spec)
        self.mj_model = mj = load_model(self.spec)
        self.timestep = float(mj.opt.timestep)
        self.task_dt = self.spec.frame_skip * self.timestep  #: dt0, Gymnasium's ``env.dt``
        if self.timestep != self.spec.timestep:
            raise ValueError(f"{path}: timestep {self.timestep:g} s, not {self.spec.timestep:g} s as in {self.spec.gym_id}")
        self.n_substeps = control_steps(self.spec, config.control_dt)
        #: the control step [s]: exactly Gymnasium's ``dt`` expression at the task's own step
        self.control_dt = self.n_substeps * self.timestep
        #: control_dt / dt0, the factor of every reward term (exactly 1.0 at the task's own step)
        self.reward_rate = self.control_dt / self.task_dt
        self.max_steps = int(round(self.spec.max_episode_steps * self.task_dt / self.control_dt))
        self.nq, self.nv, self.act_dim = mj.nq, mj.nv, mj.nu
        self.obs_dim = mj.nq - 1 + mj.nv
        self.reward_terms = ("reward_forward", "reward_ctrl") + (("reward_survive",) if self.spec.has_health else ())
        self.ctrl_low = mj.actuator_ctrlrange[:, 0].copy()
        self.ctrl_high = mj.actuator_ctrlrange[:, 1].copy()
        #: a learner's squashed action u in [-1, 1] maps to action_offset + action_scale * u, the
        #: actuators' ctrlrange (Gymnasium's action space; [-1, 1] in all three tasks)
        self.action_scale = (self.ctrl_high - self.ctrl_low) / 2.0
        self.action_offset = (self.ctrl_high + self.ctrl_low) / 2.0
        self.init_qpos = mj.qpos0.copy()
        self.c = None
        if config.physics == "c":
            plant = mujoco_c.Plant(model=mj, n_substeps=self.n_substeps, control=_law(self.ctrl_low, self.ctrl_high),
                                   act_dim=mj.nu)
            self.c = mujoco_c.CPhysics(plant, threads=config.threads or mujoco_c.threads_per_device())
            self._state0 = self.c.initial_state()
            # mjSTATE_INTEGRATION starts with time, then qpos and qvel (MuJoCo's mjtState order)
            self._q0 = int(mujoco.mj_stateSize(mj, mujoco.mjtState.mjSTATE_TIME))
            self._data0 = self._cdata(self._state0)
            return
        dev = jax.local_devices()[0]  # this process's own device (see nmrl/paper/env.py)
        self.model = mjx.put_model(mj, device=dev)
        self._data0 = mjx.make_data(self.model, device=dev)

    # ------------------------------------------------------------------ states
    def _cdata(self, s: np.ndarray) -> CData:
        q, v = self.c.split(s)
        return CData(state=jnp.asarray(mujoco_c.to_bits(s)), qpos=jnp.asarray(q, jnp.float32),
                     qvel=jnp.asarray(v, jnp.float32))

    def _parts(self, data) -> tuple[tuple[jax.Array, jax.Array], tuple[jax.Array, jax.Array]]:
        """(qpos, qvel) as (hi, lo) float32 pairs: from the float64 bits on C, (x, 0) on MJX."""
        if self.c is None:
            return (data.qpos, jnp.zeros_like(data.qpos)), (data.qvel, jnp.zeros_like(data.qvel))
        nq, nv, q0 = self.nq, self.nv, self._q0
        hi, lo = doubles.split(data.state[2 * q0: 2 * (q0 + nq + nv)])
        return (hi[:nq], lo[:nq]), (hi[nq:], lo[nq:])

    def _obs(self, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
        """Gymnasium's ``_get_obs``: (qpos[1:], qvel), qvel clipped where the task clips it."""
        c = self.spec.obs_qvel_clip
        return jnp.concatenate([qpos[1:], qvel if c is None else jnp.clip(qvel, -c, c)])

    def _healthy(self, qpos, qvel) -> jax.Array:
        """Gymnasium's ``is_healthy`` (Hopper, Walker2d) on (hi, lo) pairs; True for HalfCheetah."""
        s = self.spec
        if not s.has_health:
            return jnp.ones((), bool)
        inside = lambda p, r: doubles.greater(p, r[0]) & doubles.less(p, r[1])  # noqa: E731
        pick = lambda p, i: (p[0][i], p[1][i])  # noqa: E731
        ok = inside(pick(qpos, 1), s.healthy_z_range) & inside(pick(qpos, 2), s.healthy_angle_range)
        if s.healthy_state_range is not None:
            rest = (jnp.concatenate([qpos[0][2:], qvel[0]]), jnp.concatenate([qpos[1][2:], qvel[1]]))
            ok = ok & jnp.all(inside(rest, s.healthy_state_range))
        return ok

    def _state(self, data, key: jax.Array) -> State:
        obs = self._obs(data.qpos, data.qvel)
        zero = jnp.zeros((), jnp.float32)
        metrics = {k: zero for k in self.reward_terms}
        metrics.update(x_position=data.qpos[0], x_velocity=zero, forward_speed=zero, nonfinite=zero)
        info = {"key": key, "steps": jnp.zeros((), jnp.int32), "terminal_obs": obs,
                "terminated": zero, "truncated": zero}
        return State(data=data, obs=obs, reward=zero, done=zero, metrics=metrics, info=info)

    def reset(self, key: jax.Array) -> State:
        """Gymnasium's ``reset_model`` with noise drawn from ``key`` (a new key is kept in ``info``)."""
        key, k_q, k_v = jax.random.split(key, 3)
        s = self.spec.reset_noise_scale
        dq = jax.random.uniform(k_q, (self.nq,), minval=-s, maxval=s)
        if self.spec.qvel_noise == "normal":
            dv = s * jax.random.normal(k_v, (self.nv,))
        else:
            dv = jax.random.uniform(k_v, (self.nv,), minval=-s, maxval=s)
        if self.c is None:
            d0 = self._data0
            data = d0.replace(qpos=d0.qpos + dq, qvel=d0.qvel + dv)
        else:
            bits, qpos, qvel = self.c.shift(self._data0.state, dq, dv)
            data = CData(state=bits, qpos=qpos, qvel=qvel)
        return self._state(data, key)

    def state_at(self, qpos: np.ndarray, qvel: np.ndarray, key: jax.Array | None = None) -> State:
        """The reset state with these float64 ``qpos`` and ``qvel`` (host side, not jittable): on C
        bit for bit the MuJoCo state Gymnasium's ``set_state`` makes after ``mj_resetData``."""
        key = jax.random.key(0) if key is None else key
        if self.c is None:
            data = self._data0.replace(qpos=jnp.asarray(qpos, jnp.float32), qvel=jnp.asarray(qvel, jnp.float32))
        else:
            s = self._state0.copy()
            q, v = self.c.split(s)
            q[:], v[:] = qpos, qvel
            data = self._cdata(s)
        return self._state(data, key)

    # ------------------------------------------------------------------- step
    def step(self, state: State, action: jax.Array) -> State:
        """One control step (module docstring); with ``auto_reset`` an ended episode restarts."""
        action = self._check_action(action)
        spec, rate = self.spec, self.reward_rate
        if self.c is None:
            ctrl = jnp.clip(action, self.ctrl_low, self.ctrl_high)
            step = lambda d, _: (mjx.step(self.model, d.replace(ctrl=ctrl)), None)  # noqa: E731
            data, _ = jax.lax.scan(step, state.data, None, length=self.n_substeps)
            ok = True
        else:
            adv = self.c.advance(state.data.state, action)
            data = CData(state=adv.state, qpos=adv.qpos, qvel=adv.qvel)
            ok = adv.ok
        finite = ok & jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        data = jax.tree.map(lambda a, b: jnp.where(finite, a, b), data, self._data0)
        (qpos_b, _), (qpos, qvel) = self._parts(state.data), self._parts(data)
        x_velocity = doubles.diff((qpos[0][0], qpos[1][0]), (qpos_b[0][0], qpos_b[1][0])) / self.control_dt
        healthy = self._healthy(qpos, qvel) & finite
        terms = {"reward_forward": spec.forward_reward_weight * x_velocity,
                 "reward_ctrl": -(spec.ctrl_cost_weight * jnp.sum(jnp.square(action)))}
        if spec.has_health:
            terms["reward_survive"] = healthy.astype(jnp.float32) * spec.healthy_reward
        terms = {k: jnp.where(finite, v * rate, 0.0) for k, v in terms.items()}
        reward = terms["reward_forward"] + terms.get("reward_survive", 0.0) + terms["reward_ctrl"]
        terminated = ~finite | (~healthy if spec.terminate_when_unhealthy else False)
        steps = state.info["steps"] + 1
        truncated = steps >= self.max_steps
        done = terminated | truncated
        obs = self._obs(data.qpos, data.qvel)
        f32 = lambda b: b.astype(jnp.float32)  # noqa: E731
        metrics = {**terms, "x_position": data.qpos[0], "x_velocity": jnp.where(finite, x_velocity, 0.0),
                   "forward_speed": jnp.where(finite, x_velocity, 0.0), "nonfinite": f32(~finite)}
        key, k_reset = jax.random.split(state.info["key"])
        info = {"key": key, "steps": steps, "terminal_obs": obs, "terminated": f32(terminated),
                "truncated": f32(truncated)}
        new = State(data=data, obs=obs, reward=reward, done=f32(done), metrics=metrics, info=info)
        if self.config.auto_reset:
            fresh = self.reset(k_reset)
            new = new.replace(
                data=jax.tree.map(lambda a, b: jnp.where(done, a, b), fresh.data, data),
                obs=jnp.where(done, fresh.obs, obs),
                info={**info, "steps": jnp.where(done, 0, steps)},
            )
        return new

    def _check_action(self, action: Any) -> jax.Array:
        action = jnp.asarray(action)
        if action.shape != (self.act_dim,):
            raise ValueError(f"action must have shape ({self.act_dim},) (vmap over a batch), got shape {action.shape}")
        if not jnp.issubdtype(action.dtype, jnp.floating):
            raise TypeError(f"action must be a floating-point array, got dtype {action.dtype}")
        return action.astype(jnp.float32)
