"""The exploration options of ``nmrl train`` and ``nmrl sweep``: ``--exploration KIND`` and the
process's parameters in seconds or Hz.

``--exploration {white,nm-periods,ou,colored}`` with ``--period-s``, ``--corr-time-s``, ... sets the
learner's exploration noise (nmrl.explore's ExplorationSpec declares the parameters and their help).
The actor-critic maps them onto its own fields: ``white`` is l = 1, ``nm-periods``
l = round(period_s / control_dt) and alpha = exp(-control_dt / corr_time_s); its default stays the
paper's nm-periods with ``--l``/``--alpha``. A learner whose config holds the fields (PPO) takes them
as its own options.
"""

from __future__ import annotations

import argparse
import dataclasses


def _exploration_params() -> dict[str, tuple[type, str]]:
    """The exploration processes' parameters (name -> (type, help)) from nmrl.explore's
    ExplorationSpec (its ``cli_options``), but ``sigma`` (each learner's own ``--sigma``): one option
    ``--<name>`` each (``--period-s``, ``--corr-time-s``, ...), parsed into ``<name>``."""
    from nmrl import explore

    return {o.field: (o.type, o.help) for o in explore.cli_options() if o.field not in ("kind", "sigma")}


def add_exploration_options(p: argparse.ArgumentParser, learner) -> None:
    """The options of the exploration processes the learner takes (``Learner.explorations``)."""
    from nmrl import explore

    kinds = ", ".join(explore.KINDS)
    own = {f.name: f.default for f in dataclasses.fields(learner.config)}
    default = (f" (default: {own['exploration']})" if "exploration" in own
               else " (default: the paper's nm-periods with --l and --alpha)" if learner.name == "ac" else "")
    g = p.add_argument_group("exploration process (nmrl.explore; times in seconds, frequencies in Hz)")
    g.add_argument("--exploration", default=None, metavar="KIND",
                   help=f"the exploration noise process: {kinds}; the learner {learner.name!r} takes "
                        f"{', '.join(learner.explorations)}{default}")
    for name, (t, doc) in _exploration_params().items():
        g.add_argument("--" + name.replace("_", "-"), dest=name, type=t, default=None, metavar=name.upper(), help=doc)


def with_exploration(args: argparse.Namespace, learner, cfg, given: set[str]):
    """``cfg`` with the process of ``--exploration`` and its parameters: a learner whose config holds
    them (fields of the same names, e.g. PPO's) has them already; another maps them onto its own
    fields (``Learner.exploration``, e.g. the actor-critic's l and alpha). The config as it is when
    none is given. ValueError naming a bad process, one the learner cannot use, or a parameter that
    contradicts another option."""
    from nmrl import explore

    fields = {f.name for f in dataclasses.fields(learner.config)}
    kind = None if "exploration" in fields else getattr(args, "exploration", None)
    params = {k: getattr(args, k) for k in explore.PARAMETERS
              if k not in fields and getattr(args, k, None) is not None}
    if kind is None and not params:
        return cfg
    if kind is not None and kind not in explore.KINDS:
        raise ValueError(f"--exploration={kind!r} is unknown: choose one of {', '.join(explore.KINDS)}")
    return learner.exploration(cfg, kind, params, frozenset(given))
