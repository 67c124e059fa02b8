"""nmrl: temporally correlated exploration with exact likelihoods, and the learners that use it, on
the Half-Cheetah of P. Wawrzyński's paper (MJX or MuJoCo C inside one jitted program) and on
Gymnasium's standard MuJoCo tasks.

Layers, imports pointing down only (tests/test_structure.py): ``nmrl.physics`` (MuJoCo C inside
JAX), ``nmrl.paper`` (the paper's robot, nm-periods and actor-critic, pure JAX) and ``nmrl.tasks``
(Gymnasium's tasks) < ``nmrl.explore`` (the exploration processes) < ``nmrl.learners`` (the learner
contract, PPO) and ``nmrl.adapters`` < ``nmrl.runs`` (devices, run store, checkpoints, the driver)
< ``nmrl.analysis`` (statistics, figures, evaluation) < ``nmrl.experiments`` (sweeps and studies)
< ``nmrl.cli``.
"""

__version__ = "0.1.0"
