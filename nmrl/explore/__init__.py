"""Exploration noise processes with exact likelihoods, in physical units (pure JAX, layer 1).

* :mod:`nmrl.explore.process`: the traced state-space family (white, nm-periods, ou, colored), its
  sampler and its Kalman-filter log-density;
* :mod:`nmrl.explore.fields`: :class:`ExplorationFields`, the process and its parameters declared
  once (help, range, choices), from which the command-line options are made;
* :mod:`nmrl.explore.spec`: :class:`ExplorationSpec`, the validated setting in seconds and Hz;
* :mod:`nmrl.explore.colored`: the power-law fit of the colored process.

docs/exploration.md has the formulas, the measured approximation error and an example.
"""

from nmrl.explore.process import (NO_RESET, NoiseState, Process, belief, filter_sequence, init, log_prob, reset,
                                  sample, stack)
from nmrl.explore.fields import DEFAULT_KIND, DEFAULTS, KINDS, ExplorationFields, kind_option
from nmrl.explore.spec import (PARAMETERS, ExplorationSpec, alpha_from_corr_time, corr_time_from_alpha,
                               period_steps)

__all__ = [
    "NO_RESET", "NoiseState", "Process", "belief", "filter_sequence", "init", "log_prob", "reset", "sample", "stack",
    "DEFAULT_KIND", "DEFAULTS", "KINDS", "ExplorationFields", "kind_option", "PARAMETERS", "ExplorationSpec",
    "alpha_from_corr_time", "corr_time_from_alpha", "period_steps",
]
