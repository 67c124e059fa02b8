"""Gymnasium's v5 MuJoCo locomotion tasks with their default options, as data.

Each :class:`TaskSpec` holds what ``gymnasium/envs/mujoco/<task>_v5.py`` (Gymnasium 1.4.0, the
version pyproject.toml's ``dev`` extra pins) fixes for its task: the MJCF file in Gymnasium's
``envs/mujoco/assets``, the frame skip, the reward weights, the healthy rule, the reset noise, the
velocity clip of the observation, and the time limit of its registration
(``gymnasium/envs/__init__.py``: ``max_episode_steps=1000``). The models are read from the installed
package, not copied, so they are Gymnasium's by construction (tests/test_tasks.py steps them against
``gymnasium.make``).

* HalfCheetah-v5: reward ``1.0 * dx/dt - 0.1 |a|^2``; never terminates; reset noise
  ``qpos0 + U(-0.1, 0.1)``, ``qvel = 0.1 N(0, 1)``; obs ``(qpos[1:], qvel)`` (17).
* Hopper-v5: reward ``1.0 * dx/dt + 1.0 * healthy - 1e-3 |a|^2``; terminates when unhealthy:
  healthy is ``0.7 < z``, ``-0.2 < angle < 0.2`` and every entry of ``(qpos[2:], qvel)`` in
  (-100, 100); reset noise ``U(-5e-3, 5e-3)`` on qpos and qvel; obs ``(qpos[1:], clip(qvel, -10, 10))`` (11).
* Walker2d-v5 (``walker2d_v5.xml``: both feet with friction 1.9): as Hopper with healthy
  ``0.8 < z < 2``, ``-1 < angle < 1`` and no state range; obs (17).

``z`` is ``qpos[1]``, ``angle`` ``qpos[2]``; the ranges are open intervals, as Gymnasium's ``<``.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import pathlib
import re

#: the episode length of every task's registration, in its own control steps
MAX_EPISODE_STEPS = 1000


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """One v5 task with its default options (the names are Gymnasium's keyword arguments)."""

    gym_id: str  #: its Gymnasium id, e.g. "Hopper-v5"
    xml_file: str  #: the MJCF in gymnasium/envs/mujoco/assets
    frame_skip: int  #: MuJoCo steps per control step at the task's own control step
    timestep: float  #: the MJCF's physics timestep [s] (tests/test_tasks.py reads it from the model)
    forward_reward_weight: float
    ctrl_cost_weight: float
    healthy_reward: float = 0.0  #: 0: the task has no survival term (HalfCheetah)
    terminate_when_unhealthy: bool = False
    healthy_state_range: tuple[float, float] | None = None  #: on (qpos[2:], qvel) (Hopper)
    healthy_z_range: tuple[float, float] | None = None
    healthy_angle_range: tuple[float, float] | None = None
    reset_noise_scale: float = 0.0
    #: "normal": qvel noise is scale * N(0, 1) (HalfCheetah); "uniform": U(-scale, scale) (Hopper, Walker2d)
    qvel_noise: str = "uniform"
    obs_qvel_clip: float | None = None  #: the observation's qvel clipped to [-c, c]
    max_episode_steps: int = MAX_EPISODE_STEPS

    @property
    def has_health(self) -> bool:
        return self.healthy_z_range is not None


TASKS = {
    "halfcheetah-v5": TaskSpec(
        gym_id="HalfCheetah-v5", xml_file="half_cheetah.xml", frame_skip=5, timestep=0.01, forward_reward_weight=1.0,
        ctrl_cost_weight=0.1, reset_noise_scale=0.1, qvel_noise="normal"),
    "hopper-v5": TaskSpec(
        gym_id="Hopper-v5", xml_file="hopper.xml", frame_skip=4, timestep=0.002, forward_reward_weight=1.0,
        ctrl_cost_weight=1e-3, healthy_reward=1.0, terminate_when_unhealthy=True,
        healthy_state_range=(-100.0, 100.0), healthy_z_range=(0.7, float("inf")),
        healthy_angle_range=(-0.2, 0.2), reset_noise_scale=5e-3, obs_qvel_clip=10.0),
    "walker2d-v5": TaskSpec(
        gym_id="Walker2d-v5", xml_file="walker2d_v5.xml", frame_skip=4, timestep=0.002, forward_reward_weight=1.0,
        ctrl_cost_weight=1e-3, healthy_reward=1.0, terminate_when_unhealthy=True,
        healthy_z_range=(0.8, 2.0), healthy_angle_range=(-1.0, 1.0), reset_noise_scale=5e-3,
        obs_qvel_clip=10.0),
}


class GymnasiumMissing(ValueError):
    """The task's model lives in the gymnasium package, which is not installed."""


def assets_dir() -> pathlib.Path:
    """Gymnasium's ``envs/mujoco/assets`` folder, found without importing gymnasium."""
    found = importlib.util.find_spec("gymnasium")
    if found is None or not found.submodule_search_locations:
        raise GymnasiumMissing("the standard tasks read their models from the gymnasium package, which is "
                               "not installed: pip install -e '.[dev]'")
    return pathlib.Path(list(found.submodule_search_locations)[0]) / "envs" / "mujoco" / "assets"


def model_path(spec: TaskSpec) -> pathlib.Path:
    """The task's MJCF in the installed gymnasium package."""
    path = assets_dir() / spec.xml_file
    if not path.is_file():
        raise GymnasiumMissing(f"{path} is missing: the installed gymnasium lacks {spec.gym_id}'s model "
                               "(pip install -e '.[dev]' installs the tested version)")
    return path


_TOTAL_MASS = re.compile(r'\s+settotalmass\s*=\s*"([^"]*)"')


def load_model(spec: TaskSpec) -> mujoco.MjModel:
    """The task's compiled model, as Gymnasium compiles it. HalfCheetah's MJCF scales its masses with
    the compiler attribute ``settotalmass``, which MuJoCo 3 deprecates with a warning at every parse;
    the model is parsed without it and scaled after compiling by ``mj_setTotalmass`` and
    ``mj_setConst``, the replacement MuJoCo names, which gives every field of the model bit for bit
    (tests/test_tasks.py)."""
    import mujoco  # not at import: the tasks' data are read without MuJoCo (a command line's --help)

    path = model_path(spec)
    text = path.read_text()
    m = _TOTAL_MASS.search(text)
    if m is None:
        return mujoco.MjModel.from_xml_path(str(path))
    mj = mujoco.MjSpec.from_string(_TOTAL_MASS.sub("", text, count=1)).compile()
    mujoco.mj_setTotalmass(mj, float(m.group(1)))
    mujoco.mj_setConst(mj, mujoco.MjData(mj))
    return mj

