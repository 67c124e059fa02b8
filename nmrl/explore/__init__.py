"""Exploration noise processes with exact likelihoods, in physical units (pure JAX, layer 1).

* :mod:`nmrl.explore.process`: the traced state-space family (white, nm-periods, ou, colored), its
  sampler and its Kalman-filter log-density;
* :mod:`nmrl.explore.spec`: :class:`ExplorationSpec`, the validated setting in seconds and Hz, and
  the command-line options;
* :mod:`nmrl.explore.colored`: the power-law fit of the colored process.

docs/exploration.md has the formulas, the measured approximation error and an example.
"""

from nmrl.explore.process import (NO_RESET, NoiseState, Process, belief, filter_sequence, init, log_prob, reset,
                                  sample, stack)
from nmrl.explore.spec import (DEFAULT_KIND, DEFAULTS, KINDS, PARAMETERS, CliOption, ExplorationSpec,
                               alpha_from_corr_time, cli_options, config_option, corr_time_from_alpha, from_options,
                               period_steps)

__all__ = [
    "NO_RESET", "NoiseState", "Process", "belief", "filter_sequence", "init", "log_prob", "reset", "sample", "stack",
    "DEFAULT_KIND", "DEFAULTS", "KINDS", "PARAMETERS", "CliOption", "ExplorationSpec", "alpha_from_corr_time",
    "cli_options", "config_option", "corr_time_from_alpha", "from_options", "period_steps",
]
