"""The paper's Half-Cheetah as numbers (Sec. V-A) and its planar forward kinematics.

Conventions (see docs/model.md for the derivation and the choices):

* Joints are indexed 0..9 and links 0..8 as in Sec. V-B; link i runs from joint i to joint i+1.
  Joint 0 is the hind paw, 1 the heel, 2 the knee, 3 the hip, 4 the neck/shoulder, 5 the head,
  6 the shoulder (same place as 4), 7 the elbow, 8 the wrist, 9 the front paw.
* The plane is (x, y) in the paper, (x, z) in MuJoCo. x points forward (the head is ahead of the hip).
* phi_i (the paper's omega^l_i) is the angle of link i to the horizontal, counter-clockwise, with the
  link pointing from joint i to joint i+1.
* The relative joint angle is omega_i = phi_i - phi_{i-1} (i = 1..8), counter-clockwise positive.
  With this convention the paper's omega^0 and link lengths agree (link 1 lies at pi/3 to the
  vertical, link 2 at pi/6, the trunk is horizontal), and the first link lies at -pi/12 to the
  upward vertical when the angle is measured clockwise: phi_0 = pi/2 + pi/12.
"""

from __future__ import annotations

import numpy as np

PI = np.pi

#: Point masses at joints 0..9 [kg] (Sec. V-A).
MASSES = np.array([1.0, 1.0, 1.0, 4.0, 1.0, 2.0, 1.0, 1.0, 1.0, 1.0])

#: Link lengths 0..8 [m] (Sec. V-A).
LINK_LENGTHS = np.array(
    [
        0.2 / np.cos(PI / 12),
        0.15 / np.cos(PI / 3),
        0.25 / np.cos(PI / 6),
        1.0,
        0.3,
        0.3,
        0.25 / np.cos(PI / 9),
        0.2 / np.cos(PI / 9),
        0.15 / np.cos(PI / 9),
    ]
)

#: Initial relative angles omega^0_i of joints 1..8 (index 0 here is joint 1).
OMEGA0 = np.array([-5 / 12, 1 / 2, -2 / 3, 1 / 6, -1.0, 1 / 6, 5 / 18, 0.0]) * PI

#: Joint bounds of joints 1..8 (Sec. V-A). Joints 4 and 5 have lower == upper: they are fixed.
OMEGA_LOWER = np.array([-5 / 6, 1 / 4, -5 / 6, 1 / 6, -1.0, 1 / 18, 0.0, -2 / 3]) * PI
OMEGA_UPPER = np.array([-1 / 6, 3 / 4, -1 / 3, 1 / 6, -1.0, 1 / 2, 8 / 9, 1 / 9]) * PI

#: The actuated joints I_j = {1, 2, 3, 6, 7, 8} (reward (9), (10)) and their strengths T_i.
ACTUATED = (1, 2, 3, 6, 7, 8)
STRENGTH = np.array([60.0, 90.0, 120.0, 90.0, 60.0, 30.0])

#: Angle of link 0 to the horizontal in the initial pose: -pi/12 to the vertical (see module doc).
PHI0_INITIAL = PI / 2 + PI / 12

#: Height of the hind paw (joint 0) when the trial starts (Sec. V-C: "0.1 m above the ground").
INITIAL_HEIGHT = 0.1

#: Order of the hinge joints in the MJCF / qpos after the three root coordinates.
#: The tree is rooted at the trunk (link 3); the hind leg is a chain hip->knee->heel, the fore leg
#: shoulder->elbow->wrist.
QPOS_JOINTS = (3, 2, 1, 6, 7, 8)


def initial_link_angles() -> np.ndarray:
    """phi_i of links 0..8 in the initial pose: phi_0 = PHI0_INITIAL, phi_i = phi_{i-1} + omega^0_i."""
    return PHI0_INITIAL + np.concatenate([[0.0], np.cumsum(OMEGA0)])


def joint_positions_from_angles(phi: np.ndarray, p0: np.ndarray) -> np.ndarray:
    """Positions (10, 2) of joints 0..9 given link angles phi (9,) and the position of joint 0."""
    steps = LINK_LENGTHS[:, None] * np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    return np.concatenate([p0[None], p0[None] + np.cumsum(steps, axis=0)], axis=0)


def initial_joint_positions() -> np.ndarray:
    """Joint positions (10, 2) at reset: initial pose with the hind paw at (0, 0.1)."""
    return joint_positions_from_angles(initial_link_angles(), np.array([0.0, INITIAL_HEIGHT]))
