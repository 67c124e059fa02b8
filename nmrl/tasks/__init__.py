"""Gymnasium's standard MuJoCo locomotion tasks (v5 HalfCheetah, Hopper, Walker2d) on MJX and MuJoCo C,
with the paper's environment interface: the tasks as data (gym_v5.py), the environment (env.py), the
C state's float64 numbers read in JAX (doubles.py). docs/tasks.md describes them and how they are
checked against Gymnasium itself.

:func:`make_env` is the one way a learner builds its environment by name (``--env``): the paper's
robot or one of the tasks, from the learner's ``nmrl.paper.env.EnvConfig``.

:class:`EnvFields` declares a run's environment once (nmrl/options.py): which environment
(``--env``), its physics engine (``--physics``) and timestep, its control step and its end of a
trial. Every learner's config holds one as its group ``environment`` (``nmrl.options.group``:
``config.environment.control_dt``); the command line makes one option of each field (the option
group :data:`GROUP`), ``options.check`` validates each by its declaration (the only check of a name
such as ``--env`` or ``--physics``), and :meth:`EnvFields.check_env` what relates them.
The package imports no JAX or MuJoCo until an environment is made: the declarations are read when
a command line is built.
"""

from __future__ import annotations

import dataclasses

from typing import TYPE_CHECKING

from nmrl.options import Range, option
from nmrl.paper.control_step import DEFAULT_STOP_PROB
from nmrl.physics import PHYSICS
from nmrl.tasks.gym_v5 import TASKS, load_model

if TYPE_CHECKING:
    from nmrl.paper.env import EnvConfig

#: the paper's robot (nmrl/paper/env.py), the default environment
PAPER = "paper-cheetah"
#: every environment a learner can be given, by name
ENVS = (PAPER, *TASKS)
#: the option group (nmrl/options.py) of the environment's fields on the command line
GROUP = "environment"


@dataclasses.dataclass(frozen=True)
class EnvFields:
    """A run's environment, the group ``environment`` every learner's config holds: each field declared
    here once, with its help, its choices or range (a control step of at most 1 s: the robot's joints
    move in tenths of seconds; nmrl/runs/preflight.py checks the multiple of the physics timestep)."""

    env: str = option(PAPER, f"the environment: {', '.join(ENVS)} (docs/tasks.md)", choices=ENVS, group=GROUP)
    control_dt: float = option(0.02, "control step [s]", group=GROUP,
                               range=Range(0.0, 1.0, open_lo=True, why="seconds per control step, at most 1 s",
                                           cap=True))
    stop_prob: float = option(DEFAULT_STOP_PROB, "probability of stopping a trial after each step", group=GROUP,
                              range=Range(0.0, 1.0, why="a probability per control step"))
    trial_s: float | None = option(None, "mean trial length [s]: the stop probability per step becomes control_dt / "
                                         "trial_s, the same trial length at every control step (default: --stop-prob "
                                         "per step)", group=GROUP,
                                   range=Range(0.0, 1e6, open_lo=True, why="a mean trial length in seconds", cap=True))
    physics: str = option("mjx", "physics engine: mjx (MuJoCo-MJX, any device) or c (MuJoCo C on the CPU, float64; "
                                 "docs/performance.md)", choices=PHYSICS, group=GROUP)
    physics_timestep: float | None = option(None, "MuJoCo's timestep [s] (default: the model's 0.005 s); the control "
                                                  "step must be a multiple", group=GROUP,
                                            range=Range(0.0, 0.1, open_lo=True, why="MuJoCo's timestep in seconds",
                                                        cap=True))

    def env_config(self) -> EnvConfig:
        """The environment's own config (batched training: ``auto_reset``)."""
        from nmrl.paper.env import EnvConfig

        return EnvConfig(control_dt=self.control_dt, stop_prob=self.stop_prob, auto_reset=True,
                         physics=self.physics, trial_s=self.trial_s, timestep=self.physics_timestep)

    def check_env(self) -> None:
        """What relates the environment's fields (each field is checked by its declaration, with the
        config's others): the stop rule given once, and what a task does not take (:func:`check_env`)."""
        env_config = self.env_config()
        env_config.validate()
        check_env(self.env, env_config)


def check_env(name: str, env_config: EnvConfig) -> None:
    """ValueError in one line when the task ``name`` (one of :data:`ENVS`, checked by its declaration)
    is given an option of the paper's robot (its stop rule, its timestep) that the task does not have,
    or a control step that is not a multiple of the task's physics timestep."""
    if name == PAPER:
        return
    paper_only = {"stop_prob": env_config.stop_prob != DEFAULT_STOP_PROB, "trial_s": env_config.trial_s is not None,
                  "timestep": env_config.timestep is not None}
    given = [k for k, v in paper_only.items() if v]
    if given:
        raise ValueError(f"env={name!r} ends its episodes by its own rule and time limit and keeps its model's "
                         f"timestep: {', '.join(given)} {'is an option' if len(given) == 1 else 'are options'} of {PAPER} only")
    from nmrl.tasks.env import control_steps

    control_steps(TASKS[name], env_config.control_dt)


def mj_model(name: str):
    """The MuJoCo model the environment ``name`` (:data:`ENVS`) steps: the paper's MJCF or the task's,
    as its environment compiles it."""
    if name == PAPER:
        import mujoco

        from nmrl.paper.env import MODEL_PATH

        return mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    return load_model(TASKS[name])


def make_env(name: str, env_config: EnvConfig):
    """The environment ``name`` (:data:`ENVS`): the paper's HalfCheetah with ``env_config``, or the task
    with ``env_config``'s control step, physics, threads and auto-reset (docs/tasks.md)."""
    from nmrl.paper.env import HalfCheetah
    from nmrl.tasks.env import Task, TaskConfig

    if name == PAPER:
        return HalfCheetah(env_config)
    check_env(name, env_config)
    return Task(name, TaskConfig(control_dt=env_config.control_dt, physics=env_config.physics,
                                 threads=env_config.threads, auto_reset=env_config.auto_reset))
