"""Exploration noise processes with exact likelihoods, in physical units (pure JAX, layer 1).

* :mod:`nmrl.explore.process`: the traced state-space family (white, nm-periods, ou, colored), its
  sampler and its Kalman-filter log-density;
* :mod:`nmrl.explore.fields`: :class:`ExplorationFields`, the process and its parameters declared
  once (help, range, choices), from which the command-line options are made;
* :mod:`nmrl.explore.spec`: :class:`ExplorationSpec`, the validated setting in seconds and Hz;
* :mod:`nmrl.explore.colored`: the power-law fit of the colored process.

Each name below is imported from its module on first use (:func:`__getattr__`), so that the
declarations (``nmrl.explore.fields``, no JAX) are read without JAX when a command line is built.

docs/exploration.md has the formulas, the measured approximation error and an example.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

_PROCESS = ("NO_RESET", "NoiseState", "Process", "belief", "filter_sequence", "init", "log_prob", "reset", "sample",
            "stack")
_FIELDS = ("DEFAULT_KIND", "DEFAULTS", "KINDS", "ExplorationFields", "kind_option")
_SPEC = ("PARAMETERS", "ExplorationSpec", "alpha_from_corr_time", "corr_time_from_alpha", "period_steps")

__all__ = [*_PROCESS, *_FIELDS, *_SPEC]

if TYPE_CHECKING:  # what editors and type checkers read
    from nmrl.explore.fields import DEFAULT_KIND, DEFAULTS, KINDS, ExplorationFields, kind_option  # noqa: F401
    from nmrl.explore.process import (NO_RESET, NoiseState, Process, belief, filter_sequence, init,  # noqa: F401
                                      log_prob, reset, sample, stack)
    from nmrl.explore.spec import (PARAMETERS, ExplorationSpec, alpha_from_corr_time,  # noqa: F401
                                   corr_time_from_alpha, period_steps)


def __getattr__(name: str) -> Any:
    """The name ``name`` of :data:`__all__`, from its module (imported now if it is not yet)."""
    if name in _FIELDS:
        from nmrl.explore import fields as module
    elif name in _PROCESS:
        from nmrl.explore import process as module
    elif name in _SPEC:
        from nmrl.explore import spec as module
    else:
        raise AttributeError(f"module 'nmrl.explore' has no attribute {name!r}")
    return getattr(module, name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
