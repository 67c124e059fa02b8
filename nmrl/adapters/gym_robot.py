"""The Half-Cheetah's equations of nmrl/paper/robot.py in NumPy float64, for the Gymnasium
environment (nmrl/adapters/gym_env.py), whose step loop runs without JAX.

The same equations as :mod:`nmrl.paper.robot`, term for term (tests/test_gym_env.py checks that
the two agree to float32 rounding over a trajectory): the planar kinematics of the 10 joints with
their velocities (here by the chain rule by hand, there by ``jax.jvp``), the 31 state variables
of Table I, and the state reward terms (8), (11)-(14) with the soft step f of Sec. V-B. The torque
terms (9) and (10) come from the substeps (nmrl/paper/c_plant.py reports them) and are averaged by
the environment. The choices the paper leaves open are docs/model.md's (``[y_i = 0]`` is
``y_i <= contact_tol``; s_2 is dy_0/dt / 0.3).
"""

from __future__ import annotations

import numpy as np

from nmrl.paper import geometry as g

_L = np.asarray(g.LINK_LENGTHS, np.float64)
_W0 = np.asarray(g.OMEGA0, np.float64)  # omega^0 of joints 1..8 (index 0 = joint 1)
#: qpos index (after the 3 root coordinates) of the hinge of joint i = 1..8; None: a fixed joint
_QIDX = {i: (g.QPOS_JOINTS.index(i) if i in g.QPOS_JOINTS else None) for i in range(1, 9)}
_PHI3_0 = float(g.initial_link_angles()[3])
_HIP_0 = np.asarray(g.initial_joint_positions()[3], np.float64)
#: the links whose (cos, sin, dphi/dt) are s_11..s_31 (Table I): 0, 1, 2, 3, 6, 7, 8
_OBS_LINKS = np.array([0, 1, 2, 3, 6, 7, 8])


def soft_step(x: float) -> float:
    """The soft-step function f of Sec. V-B: 0 below 0, 2x^2 up to 1/2, 1 - 2(x-1)^2 up to 1, then 1."""
    x = float(x)
    if x <= 0.0:
        return 0.0
    if x <= 0.5:
        return 2 * x**2
    return 1 - 2 * (x - 1) ** 2 if x <= 1.0 else 1.0


def kinematics(qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(positions (10, 2), velocities (10, 2), link angles phi (9,), dphi/dt (9,)) of the joints.

    qpos = [x, z, theta, q3, q2, q1, q6, q7, q8]; omega_i = omega^0_i + q_i, the trunk's angle is
    phi_3 = phi^0_3 + theta; phi_2 = phi_3 - omega_3, phi_1 = phi_2 - omega_2, phi_0 = phi_1 - omega_1,
    phi_i = phi_{i-1} + omega_i for i = 4..8; the hip (joint 3) is the root's (x, z) shifted by its
    initial position, and the other joints follow along the links (nmrl/paper/geometry.py).
    """
    qpos = np.asarray(qpos, np.float64)
    qvel = np.asarray(qvel, np.float64)
    w = np.empty(9)
    dw = np.empty(9)
    for i in range(1, 9):
        k = _QIDX[i]
        w[i] = _W0[i - 1] + (qpos[3 + k] if k is not None else 0.0)
        dw[i] = qvel[3 + k] if k is not None else 0.0
    phi = np.empty(9)
    dphi = np.empty(9)
    phi[3], dphi[3] = _PHI3_0 + qpos[2], qvel[2]
    for i in (2, 1, 0):
        phi[i], dphi[i] = phi[i + 1] - w[i + 1], dphi[i + 1] - dw[i + 1]
    for i in range(4, 9):
        phi[i], dphi[i] = phi[i - 1] + w[i], dphi[i - 1] + dw[i]
    c, s = np.cos(phi), np.sin(phi)
    u = _L[:, None] * np.stack([c, s], axis=-1)  # link i as a vector from joint i to joint i + 1
    du = (_L * dphi)[:, None] * np.stack([-s, c], axis=-1)
    p = np.empty((10, 2))
    v = np.empty((10, 2))
    p[3], v[3] = _HIP_0 + qpos[:2], qvel[:2]
    for i in (2, 1, 0):
        p[i], v[i] = p[i + 1] - u[i], v[i + 1] - du[i]
    for i in range(4, 10):
        p[i], v[i] = p[i - 1] + u[i - 1], v[i - 1] + du[i - 1]
    return p, v, phi, dphi


def observation(p: np.ndarray, v: np.ndarray, phi: np.ndarray, dphi: np.ndarray, contact_tol: float) -> np.ndarray:
    """The 31 state variables of Table I (obs[k-1] = s_{t,k}), float64."""
    y, xd, yd = p[:, 1], v[:, 0], v[:, 1]
    on0 = float(y[0] <= contact_tol)
    on9 = float(y[9] <= contact_tol)
    head = np.array([
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
    links = _OBS_LINKS
    per_link = np.stack([np.cos(phi[links]) / 0.7, np.sin(phi[links]) / 0.7, dphi[links] / 3.0], axis=-1)
    return np.concatenate([head, per_link.reshape(-1)])


def state_rewards(p: np.ndarray, v: np.ndarray, contact_tol: float) -> dict[str, float]:
    """Reward terms (8) and (11)-(14), functions of the state s_{t+1} the step reached."""
    y, xd, yd = p[:, 1], v[:, 0], v[:, 1]
    up0 = float(y[0] > contact_tol)
    up9 = float(y[9] > contact_tol)
    speed2 = xd[3] + xd[4]
    return {
        "r8_speed": float(0.5 * speed2),
        "r11_lift": float((soft_step(0.3 * max(yd[3] + up0, yd[4] + up9) + 0.1) - 1.0)
                          * (1.0 - soft_step(1.5 * speed2))),
        "r12_heel": float(soft_step(9.0 * y[1]) - 1.0),
        "r13_knee": float(soft_step(5.0 * y[2]) - 1.0),
        "r14_head": float(soft_step(2.0 * y[5]) - 1.0),
    }


def torque_rewards(excess: np.ndarray, tau_w: np.ndarray) -> dict[str, float]:
    """Reward terms (9) and (10) from the substeps' reports (n_substeps, 6), each averaged over the
    substeps of the control step: (9) -0.05 sum_i max(|tau^0_i + a^0_i| - 1, 0), (10) -0.1 sum_i
    min(|tau^w_i|, 50) with tau^w_i the joint-limit force on joint i."""
    return {
        "r9_torque": float(-0.05 * np.sum(np.mean(excess, axis=0))),
        "r10_limit": float(-0.1 * np.sum(np.mean(np.minimum(np.abs(tau_w), 50.0), axis=0))),
    }


def extra_metrics(p: np.ndarray, v: np.ndarray, contact_tol: float) -> dict[str, float]:
    """What nmrl.paper.env reports beside the reward terms: the forward speed and position of the
    trunk (mean of joints 3 and 4) and whether the heel, knee and head touch the ground."""
    y = p[:, 1]
    return {
        "forward_speed": float(0.5 * (v[3, 0] + v[4, 0])),
        "x": float(0.5 * (p[3, 0] + p[4, 0])),
        "heel_ground": float(y[1] <= contact_tol),
        "knee_ground": float(y[2] <= contact_tol),
        "head_ground": float(y[5] <= contact_tol),
    }
