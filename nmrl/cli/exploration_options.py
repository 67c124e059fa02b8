"""The exploration options of ``nmrl train`` and ``nmrl sweep``: ``--exploration KIND`` and the
process's parameters in seconds or Hz.

``--exploration {white,nm-periods,ou,colored}`` with ``--period-s``, ``--corr-time-s``, ... sets the
learner's exploration noise. Each option is made from its field's declaration in
:class:`nmrl.explore.fields.ExplorationFields` (spelling, type, help; ``add_declared``), and each
value is checked by that declaration. The actor-critic maps them onto its own fields: ``white`` is
l = 1, ``nm-periods`` l = round(period_s / control_dt) and alpha = exp(-control_dt / corr_time_s);
its default stays the paper's nm-periods with ``--l``/``--alpha``. A learner whose config holds the
fields (PPO's group ``noise`` derives from ExplorationFields) takes them as its own options.
"""

from __future__ import annotations

import argparse

from nmrl.runs.parser import add_declared


def add_exploration_options(p: argparse.ArgumentParser, learner) -> None:
    """The options of the exploration processes the learner takes (``Learner.explorations``), one per
    field of ``ExplorationFields``, parsed into the field's name (None when not given)."""
    from nmrl import options
    from nmrl.explore import fields

    own = options.leaves(learner.config)
    default = (f" (default: {options.field(learner.config, 'exploration').default})" if "exploration" in own
               else " (default: the paper's nm-periods with --l and --alpha)" if learner.name == "ac" else "")
    g = p.add_argument_group("exploration process (nmrl.explore; times in seconds, frequencies in Hz)")
    kind = options.declaration(fields.ExplorationFields, "exploration").help
    add_declared(g, fields.ExplorationFields, "exploration", metavar="KIND",
                 help=f"{kind}; the learner {learner.name!r} takes {', '.join(learner.explorations)}{default}")
    for name in fields.PARAMS:
        add_declared(g, fields.ExplorationFields, name)


def with_exploration(args: argparse.Namespace, learner, cfg, given: set[str]):
    """``cfg`` with the process of ``--exploration`` and its parameters: a learner whose config holds
    them (fields of the same names, e.g. PPO's) has them already; another maps them onto its own
    fields (``Learner.exploration``, e.g. the actor-critic's l and alpha). The config as it is when
    none is given. ValueError naming a bad process, one the learner cannot use, or a parameter that
    contradicts another option."""
    from nmrl import options
    from nmrl.explore import fields

    names = options.leaves(learner.config)
    kind = None if "exploration" in names else getattr(args, "exploration", None)
    params = {k: getattr(args, k) for k in fields.PARAMS if k not in names and getattr(args, k, None) is not None}
    if kind is None and not params:
        return cfg
    fields.check_field("exploration", kind)
    return learner.exploration(cfg, kind, params, frozenset(given))
