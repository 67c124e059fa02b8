"""The third study's cells as data (docs/thesis-actor-critic.md): the paper's actor-critic on the
paper's robot at three control steps, the stationary policy against nm-periods of fixed durations.

Every point is Table II's learner with the paper's step sizes and update rule (the ``paper`` preset:
beta^theta = 2e-6, beta^v = 1e-5 per update, plain sgd) converted to its control step delta by the
continuous-time rules of nmrl/experiments/timescale.py (gamma, alpha, the stop rate, Delta, lambda
and the reward held per second), 32 environments, MuJoCo C physics at a 2.5 ms timestep in every cell
(8 / 2 / 1 substeps per control step at 20 / 5 / 2.5 ms), and 10^5 simulated seconds per point (3125 s
per environment, about 2 x 10^4 trials of 5 s). One cell per delta holds every arm x seed as one
``nmrl sweep --points`` program (the arms differ only in the traced l and lambda), each device's 12
points vmapped together (``--group 12``).
"""

from __future__ import annotations

from nmrl import options
from nmrl.experiments import kit
from nmrl.experiments.timescale import arm_name, at_control_step
from nmrl.experiments.timescale_cells import points_of
from nmrl.learners.ac_config import TrainConfig

DTS = (0.02, 0.005, 0.0025)  #: the control steps [s]
#: the arms: the stationary policy (None: l = 1) and nm-periods of 0.1 s and 0.2 s (l = 5 and 10 at
#: 20 ms, where Fig. 3's early lead is largest)
PERIODS = (None, 0.1, 0.2)
SEEDS = 8
NUM_ENVS = 32
SECONDS_PER_ENV = 3125.0  #: 10^5 simulated seconds per point over its 32 environments
CHUNK_S = 10.0  #: simulated seconds per environment in one chunk (a point of the learning curve)
GROUP = 12  #: points vmapped together on one device (24 points over 2 devices)
#: the primary endpoint: the deterministic policy's reward per second over 8 rollouts of 10 s from
#: perturbed starts (study 2's)
ENDPOINT = kit.Endpoint(seconds=10.0, rollouts=8, start_noise=0.05, seed=0)


def base(dt: float) -> TrainConfig:
    """The 20 ms learner every point is converted from, with this study's sizes and physics at ``dt``."""
    return options.build(TrainConfig, preset="paper", num_envs=NUM_ENVS, chunk_steps=round(CHUNK_S / dt), physics="c",
                       physics_timestep=0.0025, steps=round(SECONDS_PER_ENV / dt))


def cell_name(dt: float) -> str:
    return f"grid/dt{dt:g}"


def point_name(period: float | None, seed: int) -> str:
    return f"{arm_name(period)}_s{seed}"


def grid_cell(dt: float, seeds: int = SEEDS, seconds_per_env: float = SECONDS_PER_ENV) -> kit.Cell:
    """Every arm x seed at control step ``dt`` (module docstring)."""
    b = base(dt)
    steps = round(seconds_per_env / dt)
    names, configs = [], []
    for period in PERIODS:
        for s in range(seeds):
            c = at_control_step(b, dt, period)
            names.append(point_name(period, s))
            configs.append(options.replace(c, seed=s, steps=steps))
    return kit.Cell(cell_name(dt), "ac", steps=steps, points=points_of(names, configs), run_options={"group": GROUP})


#: the comparator's step-size check: the stationary arm at 2.5 ms with both step sizes times these
#: factors, seeds 0-3, the grid's budget
CHECK_FACTORS, CHECK_SEEDS, CHECK_DT = (3.0, 1 / 3), 4, 0.0025


def check_cell() -> kit.Cell:
    """The stationary arm at :data:`CHECK_DT` with beta^theta and beta^v both scaled by each of
    :data:`CHECK_FACTORS` (one program of 8 points, 4 per device)."""
    b = base(CHECK_DT)
    c = at_control_step(b, CHECK_DT, None)
    theta, v = c.resolved().beta_theta, c.resolved().beta_v
    names, configs = [], []
    for f in CHECK_FACTORS:
        for s in range(CHECK_SEEDS):
            names.append(f"{arm_name(None)}_x{f:.3g}_s{s}")
            configs.append(options.replace(c, seed=s, beta_theta=float(f"{theta * f:.6g}"),
                                           beta_v=float(f"{v * f:.6g}")))
    return kit.Cell(f"check/dt{CHECK_DT:g}", "ac", steps=b.budget.steps, points=points_of(names, configs),
                    run_options={"group": CHECK_SEEDS})


#: the cells in run order: the cheap 20 ms cell first (its arms show whether the budget walks), then
#: 2.5 ms (the primary family's other column), then 5 ms (the secondary family's), then the check
CELLS = (grid_cell(0.02), grid_cell(0.0025), grid_cell(0.005), check_cell())
