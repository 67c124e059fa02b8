"""Physics engines behind the environments: MuJoCo C inside the jitted program (mujoco_c.py).

MJX needs no module here: the environments call it directly. :data:`PHYSICS` names the engines an
environment can step with; the ``physics`` option of a run (nmrl/tasks/__init__.py's ``EnvFields``)
takes one of them.
"""

#: the physics engines: ``"mjx"`` (MuJoCo-MJX, float32, any device) and ``"c"`` (MuJoCo C on the CPU,
#: float64, mujoco_c.py)
PHYSICS = ("mjx", "c")
