"""The paper's ideas, pure JAX and no IO: the robot's numbers (geometry), the MJX Half-Cheetah (env),
the non-Markov noise (4) (noise) and its likelihood ratio (5)-(7) (likelihood), the networks (6) and
the toy problem of Sec. II (toy). The actor-critic built of them (Table II) is the learner of
nmrl/learners/ac_train.py. Imports nothing from the other layers of nmrl."""
