"""Gymnasium's standard MuJoCo locomotion tasks (v5 HalfCheetah, Hopper, Walker2d) on MJX and MuJoCo C,
with the paper's environment interface: the tasks as data (gym_v5.py), the environment (env.py), the
C state's float64 numbers read in JAX (doubles.py). docs/tasks.md describes them and how they are
checked against Gymnasium itself. Imports only nmrl.paper (its State) and nmrl.physics."""
