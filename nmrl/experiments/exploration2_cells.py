"""The second exploration x control-step study's cells as data (docs/exploration-study-2.md).

Every cell is the native PPO at the first study's settings (64 environments, value net 2x64, Brax's
unroll 0.4 s, 32 minibatches of 512 unrolls, 8 epochs: 102.4 simulated seconds per environment
and 256 Adam steps per iteration at every control step), with the reward scale delta / 20 ms,
trials of 5 s on average at every delta (``--trial-s 5``), MuJoCo C physics at a 2.5 ms timestep
in every cell (``--physics c --physics-timestep 0.0025``).

The screen's first phase (:data:`SIGMA_SCREEN`): the noise scale sigma in {0.064, 0.16, 0.4, 1.0}
x 2 seeds (100, 101: never grid seeds) x 4 iterations per arm and control step, each arm's time
constant at the middle of its screened range; scored by the deterministic endpoint (8 rollouts of
10 s from perturbed starts). The later phases (time constants at the chosen sigma, the grid, the
secondary parts) are these cells with the values the rules of
nmrl/experiments/exploration2_rules.py choose from the rows.
"""

from __future__ import annotations

from nmrl.experiments import kit
from nmrl.explore.spec import PAPER_CORR_TIME_S
from nmrl.paper.control_step import DELTA_0

ITERATION_S = 102.4  #: simulated seconds per environment in one PPO iteration (256 unrolls of 0.4 s)
#: the primary endpoint: the deterministic policy's reward per second over 8 rollouts of 10 s from
#: perturbed starts (0.05 rad and rad/s), the same starts for every run
ENDPOINT = kit.Endpoint(seconds=10.0, rollouts=8, start_noise=0.05, seed=0)
SIGMAS = (0.064, 0.16, 0.4, 1.0)
SCREEN_SEED0, SCREEN_SEEDS, SCREEN_ITERATIONS = 100, 2, 4
#: the paper's alpha = 0.8 per 20 ms step as a correlation time, to the 5 digits the cells' options give
NM_CORR_TIME_S = round(PAPER_CORR_TIME_S, 5)
#: each arm's exploration settings at the middle of its screened time constant
ARMS = {
    "white": {"exploration": "white"},
    "ou": {"exploration": "ou", "corr_time_s": 0.03},
    "colored": {"exploration": "colored", "beta": 0.5},
    "nms": {"exploration": "nm-periods", "period_s": 0.06, "corr_time_s": NM_CORR_TIME_S},
    "nmp": {"exploration": "nm-periods", "period_s": 0.06, "corr_time_s": NM_CORR_TIME_S, "period_wise": True},
}

#: the arms in the order tables and figures list them (ws: white with sigma by eq. (1))
ARM_ORDER = ("white", "ws", "ou", "colored", "nms", "nmp")
#: each arm's colour in every figure (matplotlib's colour cycle in that order)
ARM_COLORS = {arm: f"C{i}" for i, arm in enumerate(ARM_ORDER)}


def base(dt: float) -> dict:
    """The settings every cell at control step ``dt`` shares (module docstring); the reward scale and
    the control step to 6 significant digits (``:g``), the values the published runs' configs hold."""
    return {"num_envs": 64, "value_layers": 2, "value_width": 64, "batch_size": 512, "num_minibatches": 32,
            "epochs": 8, "reward_scale": float(f"{dt / DELTA_0:g}"), "control_dt": float(f"{dt:g}"), "trial_s": 5.0,
            "physics": "c", "physics_timestep": 0.0025}


def steps(dt: float, iterations: int) -> int:
    """The budget of ``iterations`` PPO iterations at control step ``dt``, in control steps per environment."""
    return round(iterations * ITERATION_S / dt)


def cell(name: str, dt: float, iterations: int, settings: dict, **points) -> kit.Cell:
    """A PPO cell at control step ``dt`` with :func:`base`'s settings and ``settings``, a budget of
    ``iterations`` iterations, and ``points`` (``vary``, ``seeds``, ``seed0``, ``run_options``)."""
    return kit.Cell(name, "ppo", {**base(dt), **settings}, steps=steps(dt, iterations), **points)


def sigma_cell(arm: str, dt: float) -> kit.Cell:
    """``arm``'s sigma screen at control step ``dt``: every value of :data:`SIGMAS`, the screen's seeds and budget."""
    return cell(f"screen/sigma/dt{dt:g}/{arm}", dt, SCREEN_ITERATIONS, ARMS[arm], vary=("sigma", SIGMAS),
                seeds=SCREEN_SEEDS, seed0=SCREEN_SEED0)


#: the sigma screen in run order (docs/exploration-study-2.md): white and nm-periods learned as wholes
#: (nmp) at 20 ms (cheap; scaled white follows from white's), then every arm at 2.5 ms; nms is
#: nm-periods with per-step conditional ratios
SIGMA_SCREEN = (sigma_cell("white", 0.02), sigma_cell("nmp", 0.02),
                *(sigma_cell(arm, 0.0025) for arm in ("white", "ou", "colored", "nms", "nmp")))


#: each correlated arm's time constant: the option, its screened values (the middle one is the sigma
#: screen's), and the factor an edge extension steps by
TIME_CONSTANTS = {"ou": ("corr_time_s", (0.01, 0.03, 0.09), 3.0), "colored": ("beta", (0.25, 0.5, 1.0), 2.0),
                  "nms": ("period_s", (0.02, 0.06, 0.18), 3.0), "nmp": ("period_s", (0.02, 0.06, 0.18), 3.0)}
SIGMA_FACTOR = 2.5
MAX_EXTENSIONS = 2


#: the primary family's screened settings (arm, control step), and the grid that follows them
PRIMARY = (("white", 0.02), ("nmp", 0.02), ("white", 0.0025), ("ou", 0.0025), ("colored", 0.0025),
           ("nms", 0.0025), ("nmp", 0.0025))
GRID_SEEDS, GRID_ITERATIONS, SECONDARY_SEEDS = 8, 16, 4
#: the secondary screens: OU, CN and NMs at 20 ms (run after the primary grid and the 5 ms column)
SECONDARY_SCREEN = tuple(sigma_cell(arm, 0.02) for arm in ("ou", "colored", "nms"))
SIGMA_MAX = 10.0  #: the largest --sigma nmrl takes (nmrl/runs/bounds.py)


def scaled_white_sigma(sigma_w20: float, dt: float) -> float:
    """Ws: white with sigma(dt) = sigma*(W, 20 ms) (20 ms / dt)^(1/2), which holds white noise's
    low-frequency power sigma^2 dt (eq. (1)) at its tuned 20 ms value."""
    return sigma_w20 * (0.02 / dt) ** 0.5


#: below 20 ms each minibatch's gradient is taken in this many parts of 64 unrolls (``--grad-chunks``:
#: the same Adam steps up to float rounding, a working set that fits the caches; benchmarks/
#: bench_grad_chunks.py), except in :data:`WHOLE_GRADIENT`'s cells, whose runs took it at once
GRAD_CHUNKS = 8
WHOLE_GRADIENT = ("grid/dt0.0025/white",)


def grid_cell(arm: str, dt: float, choice: dict, seeds: int, name: str | None = None,
              iterations: int = GRID_ITERATIONS) -> kit.Cell:
    """``arm`` at ``dt`` with its chosen sigma and time constant, seeds 0.. at the full budget
    (``iterations``: the grid's 16 unless given). Below 20 ms each device steps its seeds vmapped
    together (``--group``: one physics callback and one update for all of them per step, 1.2x a seed at
    a time at 2.5 ms) and takes each minibatch's gradient in :data:`GRAD_CHUNKS` parts; the 20 ms
    cells step a seed at a time, so that white's runs there are the same runs, iteration for
    iteration, as the matched-SNR cells of fewer seeds and iterations."""
    name = name or f"grid/dt{dt:g}/{arm}"
    settings = {**ARMS["white" if arm == "ws" else arm], **{k: float(f"{v:.6g}") for k, v in choice.items()}}
    if dt < 0.02 and name not in WHOLE_GRADIENT:
        settings["grad_chunks"] = GRAD_CHUNKS
    return cell(name, dt, iterations, settings, seeds=seeds, seed0=0,
                run_options={"group": seeds} if dt < 0.02 else {})


SNR_SEEDS = 3  #: seeds of the matched policies (0-2: the grid's white at 20 ms holds their iteration 16)
SNR_POLICY_ITERATIONS = (1, 4, 8)  #: iteration 1's point gives iteration 0's observation statistics
SNR_CSV = "snr.csv"
CORRELATED = ("ou", "colored", "nms", "nmp")
ASYMPTOTE_ITERATIONS = 4 * GRID_ITERATIONS  #: the asymptote's budget: 4x the grid's, at 5 ms


def arm_and_dt(name: str) -> tuple[str, float]:
    """The arm and control step a cell's directory names (``screen/sigma/dt0.0025/ou``,
    ``grid/dt0.02/white``, an extension's ``.../ou+2.5``: the arm before the ``+``)."""
    parts = name.split("/")
    return parts[-1].split("+")[0], next(float(p.removeprefix("dt")) for p in parts if p.startswith("dt"))


def grid_name(arm: str, dt: float) -> str:
    """The directory of ``arm``'s grid cell at control step ``dt``."""
    return f"grid/dt{dt:g}/{arm}"


def asymptote_name(arm: str) -> str:
    """The directory of ``arm``'s asymptote cell (5 ms, 4x the grid's budget)."""
    return f"asymptote/dt0.005/{arm}"


def snr_name(it: int) -> str:
    """The directory of white's 20 ms policies after ``it`` iterations (the SNR at matched policies)."""
    return f"snr/dt0.02/white_it{it}"
