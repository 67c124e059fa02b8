"""The Half-Cheetah's equations as functions of its joint state (Sec. V-A, V-B): the planar
kinematics, the 31 state variables of Table I, the state reward terms (8), (11)-(14) with the
soft step f, and the PD torque of Sec. V-A. Pure JAX; nmrl/paper/env.py steps the physics and
applies them (the choices the paper leaves open: its docstring and docs/model.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from nmrl.paper import c_plant
from nmrl.paper import geometry as g

_STRENGTH_CTRL = c_plant.STRENGTH_CTRL


def soft_step(x: jax.Array) -> jax.Array:
    """The soft-step function f of Sec. V-B."""
    return jnp.where(
        x <= 0.0, 0.0, jnp.where(x <= 0.5, 2 * x**2, jnp.where(x <= 1.0, 1 - 2 * (x - 1) ** 2, 1.0))
    )


def forward_kinematics(qpos: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Joint positions (10, 2) [(x, y)] and link angles phi (9,) from MJX qpos (9,).

    qpos = [x, z, theta, q3, q2, q1, q6, q7, q8]; omega_i = omega^0_i + q_i; the trunk angle is
    phi_3 = theta. See nmrl/paper/geometry.py for the conventions.
    """
    L = jnp.asarray(g.LINK_LENGTHS)
    w0 = jnp.asarray(g.OMEGA0)
    q = dict(zip(g.QPOS_JOINTS, qpos[3:]))
    w = {i: w0[i - 1] + q.get(i, 0.0) for i in range(1, 9)}
    phi3 = g.initial_link_angles()[3] + qpos[2]
    phi = [None] * 9
    phi[3] = phi3
    phi[2] = phi3 - w[3]
    phi[1] = phi[2] - w[2]
    phi[0] = phi[1] - w[1]
    for i in range(4, 9):
        phi[i] = phi[i - 1] + w[i]
    phi = jnp.stack(phi)
    u = jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1) * L[:, None]
    hip = jnp.asarray(g.initial_joint_positions()[3]) + qpos[:2]
    p = [None] * 10
    p[3] = hip
    for i in (2, 1, 0):
        p[i] = p[i + 1] - u[i]
    for i in range(4, 10):
        p[i] = p[i - 1] + u[i - 1]
    return jnp.stack(p), phi


def kinematics(qpos: jax.Array, qvel: jax.Array):
    """(positions (10,2), velocities (10,2), phi (9,), dphi/dt (9,)) by forward-mode autodiff."""
    (p, phi), (v, dphi) = jax.jvp(forward_kinematics, (qpos,), (qvel,))
    return p, v, phi, dphi


def observation(p, v, phi, dphi, contact_tol: float) -> jax.Array:
    """The 31 state variables of Table I (obs[k-1] = s_{t,k})."""
    y, xd, yd = p[:, 1], v[:, 0], v[:, 1]
    on0 = (y[0] <= contact_tol).astype(p.dtype)
    on9 = (y[9] <= contact_tol).astype(p.dtype)
    head = jnp.stack([
        (y[0] - 0.1) / 0.1,
        yd[0] / 0.3,
        (on0 - 0.5) / 0.5,
        ((y[3] + y[4]) / 2 - 0.6) / 0.2,
        (xd[3] + xd[4]) / 2 - 1.0,
        yd[3] / 0.3,
        yd[4] / 0.3,
        (y[9] - 0.1) / 0.1,
        yd[9] / 0.3,
        (on9 - 0.5) / 0.5,
    ])
    links = jnp.array([0, 1, 2, 3, 6, 7, 8])
    per_link = jnp.stack([jnp.cos(phi[links]) / 0.7, jnp.sin(phi[links]) / 0.7, dphi[links] / 3.0], axis=-1)
    return jnp.concatenate([head, per_link.reshape(-1)])


def state_rewards(p, v, contact_tol: float) -> dict[str, jax.Array]:
    """Reward terms (8) and (11)-(14), functions of the state s_{t+1}."""
    y, xd, yd = p[:, 1], v[:, 0], v[:, 1]
    up0 = (y[0] > contact_tol).astype(p.dtype)
    up9 = (y[9] > contact_tol).astype(p.dtype)
    speed2 = xd[3] + xd[4]
    return {
        "r8_speed": 0.5 * speed2,
        "r11_lift": (soft_step(0.3 * jnp.maximum(yd[3] + up0, yd[4] + up9) + 0.1) - 1.0)
        * (1.0 - soft_step(1.5 * speed2)),
        "r12_heel": soft_step(9.0 * y[1]) - 1.0,
        "r13_knee": soft_step(5.0 * y[2]) - 1.0,
        "r14_head": soft_step(2.0 * y[5]) - 1.0,
    }


def pd_torque(qpos: jax.Array, qvel: jax.Array, a0_ctrl: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(tau, tau^0 + a^0) for the 6 actuated joints in actuator order (Sec. V-A)."""
    q, qd = qpos[3:], qvel[3:]
    tau0 = (2.0 / jnp.pi) * jnp.arctan(-2.0 * q - 0.05 * qd)
    pre = tau0 + a0_ctrl
    return jnp.asarray(_STRENGTH_CTRL, qpos.dtype) * jnp.clip(pre, -1.0, 1.0), pre
