"""The learner's options of ``nmrl train`` and ``nmrl sweep``, generated from its config.

Every field of the learner's config (nmrl/learners/contract.py) whose declaration (nmrl/options.py)
makes it an option is one option ``--<flag>`` of the command, spelled and explained by that
declaration (the actor-critic's :class:`nmrl.learners.ac_config.TrainConfig`: ``--beta-theta 2e-6``,
``--num-envs 256``, ``--actor-opt clip:10,sgd``, ...); :func:`config_from_args` builds the config
from the options given, with the exploration process applied (nmrl/cli/exploration_options.py).
The learner and JAX are imported only when a command asks (after nmrl.runs.devices.configure has
set the host device count). A run given no budget takes its config's (the actor-critic's:
nmrl.learners.ac_config.DEFAULT_STEPS).
"""

from __future__ import annotations

import argparse

from nmrl.cli.exploration_options import with_exploration
from nmrl.runs.parser import add_declared, field_type

__all__ = ["add_config_options", "config_from_args", "field_type", "get_learner", "given_options", "learner_names"]


def get_learner(name: str | None = None):
    """The learner ``name`` (default: the actor-critic); ValueError naming it and the allowed ones."""
    from nmrl import learners

    return learners.get(name or learners.DEFAULT)


def learner_names() -> list[str]:
    """The names of the learners ``--learner`` takes."""
    from nmrl import learners

    return learners.names()


def _options(learner, skip: set[str] = frozenset(), group: str | None = None) -> list[str]:
    """The config's leaves (by flat name, walking its groups) that are options of the option group
    ``group`` (None: the learner's own)."""
    from nmrl import options

    return [name for name, decl in options.declarations(learner.config).items()
            if name not in skip and decl.cli and decl.group == group]


def add_config_options(p: argparse.ArgumentParser, skip: set[str] = frozenset(), learner=None) -> None:
    """One option per field of the learner's config (nmrl/learners/contract.py), spelled and explained
    by the field's declaration (nmrl/options.py), with its default unless the help names it: the
    learner's own fields, then the environment's (nmrl.tasks.EnvFields, their own group)."""
    from nmrl import tasks

    learner = learner or get_learner()
    own = p.add_argument_group(f"options of the learner {learner.name!r} ({learner.doc})" if learner.doc
                               else f"options of the learner {learner.name!r}")
    env = p.add_argument_group("the environment (nmrl/tasks/, docs/tasks.md)")
    for group, g in ((None, own), (tasks.GROUP, env)):
        for name in _options(learner, skip, group):
            add_declared(g, learner.config, name, help=learner.help.get(name, ""))


def given_options(args: argparse.Namespace, skip: set[str] = frozenset()) -> dict:
    """The config fields of the command's learner given on the command line (flat name -> value)."""
    from nmrl import options

    learner = get_learner(getattr(args, "learner", None))
    given = {name: getattr(args, name) for name in options.leaves(learner.config)
             if name not in skip and getattr(args, name, None) is not None}
    if getattr(args, "resume", False):  # a resumed run keeps its own control step
        return given
    return {**_task_control_dt(given), **given}


def _task_control_dt(given: dict) -> dict:
    """``{"control_dt": the task's own step}`` (frame skip x timestep, Gymnasium's ``dt``) for a
    Gymnasium task given by ``--env`` without ``--control-dt``; nothing otherwise."""
    env = given.get("env")
    if env is None or "control_dt" in given:
        return {}
    from nmrl.tasks.gym_v5 import TASKS

    return {"control_dt": TASKS[env].frame_skip * TASKS[env].timestep} if env in TASKS else {}


def config_from_args(args: argparse.Namespace, skip: set[str] = frozenset()):
    """The learner's config from the options given, with the exploration process (``--exploration``
    and its parameters in seconds/Hz) applied by the learner (nmrl/cli/exploration_options.py)."""
    learner = get_learner(getattr(args, "learner", None))
    given = given_options(args, skip)
    from nmrl import options

    return with_exploration(args, learner, options.build(learner.config, **given), set(given))
