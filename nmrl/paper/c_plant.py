"""The paper's Half-Cheetah as a :class:`nmrl.physics.mujoco_c.Plant`: the model, the per-substep
PD torque of Sec. V-A in NumPy (float64) and the joint-limit torque tau^w of eq. (10) as MuJoCo's
``jointlimitfrc`` sensor on each actuated joint.

Per substep the law reports ``max(|tau^0_i + a^0_i| - 1, 0)`` (the excess over saturation of eq. (9))
for the 6 actuated joints, and the model reports their joint-limit constraint force (the force of
the limit's constraint row, which is what the MJX path's ``J^T f`` over the limit rows gives on a
hinge). Both are in actuator order (= qpos order of the hinges), as on the MJX path.
"""

from __future__ import annotations

import mujoco
import numpy as np

from nmrl.paper import geometry as g
from nmrl.physics.mujoco_c import Plant

#: Actuator order of the MJCF (= qpos order of the hinges) mapped to the action index j - 1.
ACT_OF_CTRL = np.array([g.ACTUATED.index(i) for i in g.QPOS_JOINTS])
STRENGTH_CTRL = g.STRENGTH[ACT_OF_CTRL]


def pd_law(qpos: np.ndarray, qvel: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sec. V-A for a batch: ``ctrl = T_i clip(tau^0_i + a^0_i, -1, 1)`` with a^0 = 0.1 a (Sec. V-C)
    and tau^0_i = 2/pi arctan(-2 q_i - 0.05 dq_i/dt); reports the excess ``max(|tau^0 + a^0| - 1, 0)``."""
    a0 = 0.1 * action[:, ACT_OF_CTRL]
    tau0 = (2.0 / np.pi) * np.arctan(-2.0 * qpos[:, 3:] - 0.05 * qvel[:, 3:])
    pre = tau0 + a0
    return STRENGTH_CTRL * np.clip(pre, -1.0, 1.0), np.maximum(np.abs(pre) - 1.0, 0.0)


def with_limit_sensors(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """The model compiled with a ``jointlimitfrc`` sensor on each hinge after the root (actuator
    order); sensors change no dynamics."""
    for j in spec.joints:
        if j.type == mujoco.mjtJoint.mjJNT_HINGE and j.name != "rooty":
            spec.add_sensor(type=mujoco.mjtSensor.mjSENS_JOINTLIMITFRC, objtype=mujoco.mjtObj.mjOBJ_JOINT,
                            objname=j.name)
    return spec.compile()


def plant(model: mujoco.MjModel, n_substeps: int) -> Plant:
    """The C plant of a model made by :func:`with_limit_sensors` and set to the run's options."""
    return Plant(model=model, n_substeps=n_substeps, control=pd_law,
                 act_dim=len(g.ACTUATED), n_law_report=len(g.ACTUATED))
