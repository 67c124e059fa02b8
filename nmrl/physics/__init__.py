"""Physics engines behind the environments: MuJoCo C inside the jitted program (mujoco_c.py).

MJX needs no module here: the environments call it directly.
"""
