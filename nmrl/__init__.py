"""nmrl: non-Markov-period actor-critic for the paper's Half-Cheetah (Wawrzynski).

Layers, imports pointing down only (tests/test_structure.py): ``nmrl.physics`` (MuJoCo C inside
JAX) and ``nmrl.paper`` (the paper's ideas, pure JAX) < ``nmrl.runs`` (devices, run store, checkpoints, the driver) < ``nmrl.analysis``
(statistics, figures, evaluation) < ``nmrl.experiments`` (Fig. 3 sweep, finer-delta study) <
``nmrl.cli``.
"""

__version__ = "0.1.0"
