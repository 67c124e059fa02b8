"""The library's front door: what ``nmrl train`` does, from Python, in three calls.

    import nmrl

    cfg = nmrl.config("ac", preset="fast_clip", num_envs=64, steps=4000, l=10)   # validated
    rows = nmrl.train(cfg, "runs/api_demo")     # a run directory as `nmrl train --out` writes it
    print(rows[-1]["avg_reward"])               # the metrics rows of metrics.jsonl

    trainer = nmrl.make_train(cfg)              # or drive the pure functions yourself:
    ts = jax.jit(trainer.init)(jax.random.PRNGKey(cfg.budget.seed))
    ts, metrics = jax.jit(trainer.chunk)(ts)    # one chunk of cfg.budget.chunk_steps control steps

:func:`config` builds a learner's config from its name (``nmrl.learners.names()``) and the same
fields the command line sets (``--num-envs 64`` is ``num_envs=64``) and checks it as the command does,
so a bad value raises one ValueError naming it and what is allowed. :func:`train` is
:func:`nmrl.runs.driver.train` (resume, checkpoints, signals); :func:`make_train` is the learner's
``make`` (``Learner.make``, nmrl/learners/contract.py) on the resolved config: a ``Trainer`` whose
``init(key)`` and ``chunk(ts)`` are pure and jit-able, one chunk a ``lax.scan`` over control steps.
"""

from __future__ import annotations

from typing import Any

from nmrl import options
from nmrl.learners import contract as learners
from nmrl.learners.contract import Trainer
from nmrl.runs.driver import train
from nmrl.runs.preflight import check_config

__all__ = ["config", "make_train", "train"]


def config(learner: str = learners.DEFAULT, **fields: Any) -> Any:
    """The config of ``learner`` with ``fields`` (the command line's option names with ``_``), checked
    as ``nmrl train`` checks it: ValueError naming a bad value, TypeError naming an unknown field."""
    cls = learners.get(learner).config
    known = set(options.leaves(cls))
    unknown = sorted(set(fields) - known)
    if unknown:
        raise TypeError(f"learner {learner!r} has no fields {unknown}; its fields: {', '.join(sorted(known))}")
    cfg = options.build(cls, **fields)
    check_config(cfg)
    return cfg


def make_train(cfg: Any) -> Trainer:
    """The learner's training functions for ``cfg`` (checked, then resolved: a preset's step sizes
    filled in), with its environment built from ``cfg``."""
    check_config(cfg)
    cfg = cfg.resolved()
    return learners.of(cfg).make(cfg)
