"""The paper's ideas, pure JAX and no IO: the robot's numbers (geometry), the MJX Half-Cheetah (env),
the non-Markov noise and its likelihood ratio (noise), the networks, the actor-critic (learner) and
the toy problem of Sec. II (toy). Imports nothing from the other layers of nmrl."""
