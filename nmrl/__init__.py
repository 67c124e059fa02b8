"""nmrl: non-Markov-period actor-critic for the paper's Half-Cheetah (Wawrzynski)."""

__version__ = "0.1.0"
