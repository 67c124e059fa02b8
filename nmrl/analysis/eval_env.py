"""The environment an evaluation rolls a policy out in, built once per setting and cached.

Every evaluation (``nmrl eval``: nmrl/analysis/evaluate.py and, for a Gymnasium task,
nmrl/analysis/task_eval.py; a study's endpoint: nmrl/analysis/endpoint.py) runs a run's policy in
the run's own environment (its ``env``, control step, physics and MuJoCo timestep) without
automatic reset, so that a rollout is one trial and its end is seen: the paper's robot also never
stops a trial at random (stop probability 0); a task ends by its own rule and time limit
(docs/tasks.md). Building an environment loads its model (and, on MuJoCo C, a thread pool), so
:func:`eval_env` keeps the few in use.
"""

from __future__ import annotations

import functools
from typing import Any

from nmrl import tasks
from nmrl.paper.env import EnvConfig


@functools.lru_cache(maxsize=8)
def eval_env(name: str, control_dt: float, physics: str = "mjx", timestep: float | None = None):
    """The environment ``name`` (``nmrl.tasks.ENVS``) at ``control_dt`` on ``physics`` (and, for the
    paper's robot, MuJoCo's ``timestep``; None: the model's), without automatic reset; the paper's
    robot with stop probability 0."""
    if name == tasks.PAPER:
        return tasks.make_env(name, EnvConfig(control_dt=control_dt, stop_prob=0.0, auto_reset=False,
                                              physics=physics, timestep=timestep))
    return tasks.make_env(name, EnvConfig(control_dt=control_dt, auto_reset=False, physics=physics, timestep=timestep))


def of_config(config: Any):
    """:func:`eval_env` of a run's config (fields a config predates at the values runs had then: the
    paper's robot, MJX, the model's timestep)."""
    e = config.environment
    return eval_env(e.env, float(e.control_dt), e.physics, e.physics_timestep)
