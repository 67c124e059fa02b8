"""nmrl: temporally correlated exploration with exact likelihoods, and the learners that use it, on
the Half-Cheetah of P. Wawrzyński's paper (MJX or MuJoCo C inside one jitted program) and on
Gymnasium's standard MuJoCo tasks.

Layers, imports pointing down only (tests/test_structure.py): ``nmrl.physics`` (MuJoCo C inside
JAX), ``nmrl.paper`` (the paper's robot, nm-periods and actor-critic, pure JAX) and ``nmrl.tasks``
(Gymnasium's tasks) < ``nmrl.explore`` (the exploration processes) < ``nmrl.learners`` (the learner
contract, PPO) and ``nmrl.adapters`` < ``nmrl.runs`` (devices, run store, checkpoints, the driver)
< ``nmrl.analysis`` (statistics, figures, evaluation) < ``nmrl.experiments`` (sweeps and studies)
< ``nmrl.cli``.

The front door (nmrl/runs/api.py): ``nmrl.config(learner, **fields)``, ``nmrl.train(config, out)``
and ``nmrl.make_train(config)``, imported on first use so that ``import nmrl`` (and the command
line's ``--help``) does not load JAX.
"""

__version__ = "0.1.0"
__all__ = ["config", "make_train", "train"]


def __getattr__(name: str):
    if name in __all__:
        from nmrl.runs import api
        return getattr(api, name)
    raise AttributeError(f"module 'nmrl' has no attribute {name!r}")
