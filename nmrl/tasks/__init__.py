"""Gymnasium's standard MuJoCo locomotion tasks (v5 HalfCheetah, Hopper, Walker2d) on MJX and MuJoCo C,
with the paper's environment interface: the tasks as data (gym_v5.py), the environment (env.py), the
C state's float64 numbers read in JAX (doubles.py). docs/tasks.md describes them and how they are
checked against Gymnasium itself.

:func:`make_env` is the one way a learner builds its environment by name (``--env``): the paper's
robot or one of the tasks, from the learner's ``nmrl.paper.env.EnvConfig``.
"""

from __future__ import annotations

from nmrl.paper.env import DEFAULT_STOP_PROB, EnvConfig, HalfCheetah
from nmrl.tasks.env import Task, TaskConfig, control_steps
from nmrl.tasks.gym_v5 import TASKS

#: the paper's robot (nmrl/paper/env.py), the default environment
PAPER = "paper-cheetah"
#: every environment a learner can be given, by name
ENVS = (PAPER, *TASKS)


def check_env(name: str, env_config: EnvConfig) -> None:
    """ValueError in one line for an unknown ``name`` (listing the known ones) or, for a task, an
    option of the paper's robot (its stop rule, its timestep) that the task does not have, or a control
    step that is not a multiple of the task's physics timestep."""
    if name not in ENVS:
        raise ValueError(f"env={name!r} is unknown: choose one of {', '.join(ENVS)}")
    if name == PAPER:
        return
    paper_only = {"stop_prob": env_config.stop_prob != DEFAULT_STOP_PROB, "trial_s": env_config.trial_s is not None,
                  "timestep": env_config.timestep is not None}
    given = [k for k, v in paper_only.items() if v]
    if given:
        raise ValueError(f"env={name!r} ends its episodes by its own rule and time limit and keeps its model's "
                         f"timestep: {', '.join(given)} {'is an option' if len(given) == 1 else 'are options'} of {PAPER} only")
    control_steps(TASKS[name], env_config.control_dt)


def make_env(name: str, env_config: EnvConfig):
    """The environment ``name`` (:data:`ENVS`): the paper's HalfCheetah with ``env_config``, or the task
    with ``env_config``'s control step, physics, threads and auto-reset (docs/tasks.md)."""
    check_env(name, env_config)
    if name == PAPER:
        return HalfCheetah(env_config)
    return Task(name, TaskConfig(control_dt=env_config.control_dt, physics=env_config.physics,
                                 threads=env_config.threads, auto_reset=env_config.auto_reset))
