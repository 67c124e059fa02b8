"""MuJoCo C physics inside a jitted JAX program: a robot stepped by ``mujoco.batch`` through
``jax.pure_callback``, its whole integration state carried in the JAX state.

The boundary is generic: a :class:`Plant` is a MuJoCo model, the number of substeps of one control
step, a per-substep control law (NumPy, float64: ``ctrl`` from the current ``qpos``, ``qvel`` and
the control step's action, plus what the law reports) and what each substep reports from the model
(its sensors). :class:`CPhysics` turns a plant into one pure function

    ``advance(state, action) -> Advanced(state, qpos, qvel, reports, ok)``

that JAX can ``jit``, ``vmap`` (any number of batch axes; the callback receives the whole batch),
``lax.map``, ``lax.scan`` and ``shard_map``: the state is MuJoCo's ``mjSTATE_INTEGRATION`` vector
(time, qpos, qvel, act, warm start, ctrl, applied forces, ...) as float64 bits (two uint32 per
number, so it needs no ``jax_enable_x64``), written into a ``mujoco.batch.Batch`` before the control
step and read back after it. Nothing else persists between calls, so the result depends only on
the arguments: checkpoints, resume, vmapped points and devices see an ordinary array. The batch
steps its simulations on ``threads`` threads and gives bit-identical results at any thread count.

A MuJoCo warning raised during the control step (e.g. ``mjWARN_BADQACC``, after which MuJoCo
resets the simulation), an error raised by MuJoCo, or a non-finite qpos/qvel clears ``ok`` for that
simulation; the caller treats it as a non-finite physics state (the environment's trial stop).
"""

from __future__ import annotations

import dataclasses
import os
import threading
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import mujoco.batch
import numpy as np

#: What a control step carries: MuJoCo's integration state (mj_getState / mj_setState).
STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION

#: ``control(qpos (B, nq), qvel (B, nv), action (B, A)) -> (ctrl (B, nu), report (B, R))``, float64.
ControlLaw = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


class PhysicsUnsupported(ValueError):
    """The C physics cannot run here (a device that is not the CPU, a model feature it lacks)."""


@dataclasses.dataclass(frozen=True, eq=False)
class Plant:
    """A robot for the C path: ``model`` (with the sensors the reports need), ``n_substeps`` MuJoCo
    steps per control step, ``control`` (:data:`ControlLaw`, applied before every substep with the
    action held), ``act_dim`` and ``n_law_report`` (the widths of the action and of the law's report).

    Each substep reports ``concat(law report, sensordata)`` with the sensors MuJoCo computed during
    that substep (for ``mj_step``: at the state the substep starts from, like any derived field).
    """

    model: mujoco.MjModel
    n_substeps: int
    control: ControlLaw
    act_dim: int
    n_law_report: int = 0

    @property
    def n_report(self) -> int:
        return self.n_law_report + int(self.model.nsensordata)


class Advanced(NamedTuple):
    """One control step of C physics (leading batch axes as the inputs')."""

    state: jax.Array  #: (2 nstate,) uint32: the float64 integration state after the step
    qpos: jax.Array  #: (nq,) float32
    qvel: jax.Array  #: (nv,) float32
    reports: jax.Array  #: (n_substeps, n_report) float32, one row per substep
    ok: jax.Array  #: () bool: no warning, no error, finite state


def check_supported(model: mujoco.MjModel) -> None:
    """Refuse, in one line, what the C path cannot run: a device other than the CPU, or a model whose
    simulation keeps state outside ``mjSTATE_INTEGRATION`` between steps (sleep or plugins)."""
    backend = jax.default_backend()
    if backend != "cpu":
        raise PhysicsUnsupported(f"--physics c runs on the CPU only; this JAX's default device is {backend!r} "
                                 "(use --physics mjx)")
    if model.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP):
        raise PhysicsUnsupported("--physics c does not support a model with sleep enabled (use --physics mjx)")
    if model.nplugin:
        raise PhysicsUnsupported("--physics c does not support a model with engine plugins (use --physics mjx)")


def threads_per_device() -> int:
    """This process's cores (its CPU affinity) shared out over its JAX devices, at least 1: each
    device calls the physics from its own thread, so together they keep every core busy."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, cores // len(jax.local_devices()))


def to_bits(x: np.ndarray) -> np.ndarray:
    """float64 (..., n) as its uint32 words (..., 2 n)."""
    x = np.ascontiguousarray(x, np.float64)
    return x.view(np.uint32).reshape(*x.shape[:-1], 2 * x.shape[-1])


def from_bits(b: np.ndarray) -> np.ndarray:
    """uint32 words (..., 2 n) as float64 (..., n) (the inverse of :func:`to_bits`)."""
    b = np.ascontiguousarray(b, np.uint32)
    return b.view(np.float64).reshape(*b.shape[:-1], b.shape[-1] // 2)


class CPhysics:
    """A :class:`Plant` stepped in C; see the module docstring. ``threads``: the batch's threads."""

    def __init__(self, plant: Plant, threads: int = 1):
        check_supported(plant.model)
        if not (isinstance(threads, int) and threads >= 1):
            raise ValueError(f"threads must be an integer >= 1, got {threads!r}")
        self.plant = plant
        self.threads = threads
        m = plant.model
        self.nstate = int(mujoco.mj_stateSize(m, STATE_SPEC))
        self._qpos = slice(*_component(m, mujoco.mjtState.mjSTATE_QPOS))
        self._qvel = slice(*_component(m, mujoco.mjtState.mjSTATE_QVEL))
        self._ctrl = slice(*_component(m, mujoco.mjtState.mjSTATE_CTRL))
        # Each calling thread (one per XLA device) has its own batches, kept for the object's life.
        self._batches: dict[tuple[int, int], mujoco.batch.Batch] = {}
        self._lock = threading.Lock()

    # ---------------------------------------------------------------- the initial state
    def initial_state(self) -> np.ndarray:
        """float64 (nstate,): ``mj_resetData`` (the model's qpos0, at rest, zero warm start)."""
        d = mujoco.MjData(self.plant.model)
        mujoco.mj_resetData(self.plant.model, d)
        s = np.empty(self.nstate)
        mujoco.mj_getState(self.plant.model, d, s, STATE_SPEC)
        return s

    def split(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(qpos, qvel) of float64 states (..., nstate)."""
        return state[..., self._qpos], state[..., self._qvel]

    # ---------------------------------------------------------------- the host side
    def _batch(self, n: int) -> mujoco.batch.Batch:
        """This thread's batch of ``n`` simulations (a Batch serves one caller at a time)."""
        key = (threading.get_ident(), n)
        with self._lock:
            b = self._batches.get(key)
            if b is None:
                b = mujoco.batch.Batch(self.plant.model, n, self.threads)
                if self.plant.model.nsensordata:
                    b.bind("sensordata")  # an output is copied out from the first call after it is bound
                self._batches[key] = b
        return b

    def host_step(self, state: np.ndarray, action: np.ndarray):
        """One control step of B simulations in NumPy: float64 ``state`` (B, nstate), ``action``
        (B, A) -> (state, reports (B, n_substeps, n_report), ok (B,))."""
        p = self.plant
        n = state.shape[0]
        b = self._batch(n)
        b.state[...] = state
        b.warning[...] = 0
        ok = np.ones(n, bool)
        reports = np.zeros((n, p.n_substeps, p.n_report))
        qpos, qvel = b.state[:, self._qpos], b.state[:, self._qvel]
        for k in range(p.n_substeps):
            ctrl, law = p.control(qpos, qvel, action)
            b.state[:, self._ctrl] = ctrl
            try:
                b.step()
            except mujoco.batch.SimulationError as e:
                ok[e.ids] = False
            reports[:, k, : p.n_law_report] = law
            if p.model.nsensordata:
                reports[:, k, p.n_law_report:] = b.sensordata
        ok &= ~np.any(b.warning[..., 1] > 0, axis=-1)
        out = np.array(b.state)
        ok &= np.all(np.isfinite(out), axis=-1)
        return out, reports, ok

    def _callback(self, bits: np.ndarray, action: np.ndarray):
        lead = bits.shape[:-1]
        state = from_bits(bits.reshape(-1, 2 * self.nstate))
        act = np.asarray(action, np.float64).reshape(-1, self.plant.act_dim)
        out, reports, ok = self.host_step(state, act)
        qpos, qvel = self.split(out)
        with np.errstate(over="ignore", invalid="ignore"):
            f32 = lambda x: x.astype(np.float32)  # noqa: E731
            return (to_bits(out).reshape(*lead, 2 * self.nstate), f32(qpos).reshape(*lead, -1),
                    f32(qvel).reshape(*lead, -1), f32(reports).reshape(*lead, *reports.shape[1:]),
                    ok.reshape(lead))

    # ---------------------------------------------------------------- the JAX side
    def advance(self, state: jax.Array, action: jax.Array) -> Advanced:
        """One control step inside JAX: ``state`` (2 nstate,) uint32, ``action`` (act_dim,) float.
        Batch axes are handed to one callback (``vmap_method='broadcast_all'``)."""
        p = self.plant
        m = p.model
        shapes = Advanced(
            state=jax.ShapeDtypeStruct((2 * self.nstate,), jnp.uint32),
            qpos=jax.ShapeDtypeStruct((m.nq,), jnp.float32),
            qvel=jax.ShapeDtypeStruct((m.nv,), jnp.float32),
            reports=jax.ShapeDtypeStruct((p.n_substeps, p.n_report), jnp.float32),
            ok=jax.ShapeDtypeStruct((), jnp.bool_),
        )
        out = jax.pure_callback(self._callback, tuple(shapes), state, action, vmap_method="broadcast_all")
        return Advanced(*out)

    def shift(self, state: jax.Array, dq: jax.Array, dv: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(state, qpos, qvel) with ``dq`` added to qpos and ``dv`` to qvel (in float64, on the host)."""
        m = self.plant.model
        shapes = (jax.ShapeDtypeStruct((2 * self.nstate,), jnp.uint32), jax.ShapeDtypeStruct((m.nq,), jnp.float32),
                  jax.ShapeDtypeStruct((m.nv,), jnp.float32))
        return jax.pure_callback(lambda b, q, v: _shift_host(self, b, q, v), shapes, state, dq, dv,
                                 vmap_method="broadcast_all")


def _shift_host(self, bits, dq, dv):
    lead = bits.shape[:-1]
    state = from_bits(bits.reshape(-1, 2 * self.nstate)).copy()
    state[:, self._qpos] += np.asarray(dq, np.float64).reshape(len(state), -1)
    state[:, self._qvel] += np.asarray(dv, np.float64).reshape(len(state), -1)
    qpos, qvel = self.split(state)
    return (to_bits(state).reshape(*lead, -1), qpos.astype(np.float32).reshape(*lead, -1),
            qvel.astype(np.float32).reshape(*lead, -1))


def _component(model: mujoco.MjModel, part: mujoco.mjtState) -> tuple[int, int]:
    """[start, stop) of one state component inside the ``mjSTATE_INTEGRATION`` vector."""
    start = 0
    for bit in range(mujoco.mjtState.mjNSTATE.value):
        spec = 1 << bit
        if not (int(STATE_SPEC) & spec):
            continue
        size = int(mujoco.mj_stateSize(model, spec))
        if spec == int(part):
            return start, start + size
        start += size
    raise ValueError(f"{part} is not part of mjSTATE_INTEGRATION")
