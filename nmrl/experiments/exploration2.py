"""The second exploration x control-step study (docs/exploration-study-2.md) as data on the kit.

Every cell is the native PPO at the first study's settings (64 environments, value net 2x64, Brax's
unroll 0.4 s, 32 minibatches of 512 unrolls, 8 epochs: 102.4 simulated seconds per environment
and 256 Adam steps per iteration at every control step), with the reward scale delta / 20 ms,
trials of 5 s on average at every delta (``--trial-s 5``), MuJoCo C physics at a 2.5 ms timestep
in every cell (``--physics c --physics-timestep 0.0025``).

The screen's first phase (:data:`SIGMA_SCREEN`): the noise scale sigma in {0.064, 0.16, 0.4, 1.0}
x 2 seeds (100, 101: never grid seeds) x 4 iterations per arm and control step, each arm's time
constant at the middle of its screened range; scored by the deterministic endpoint (8 rollouts of
10 s from perturbed starts). The later phases (time constants at the chosen sigma, the grid) are
made from these rows by the rules the pre-registration states.

    python -m nmrl.experiments.exploration2 run --out runs/exploration2 [--published results/exploration2/runs]
    python -m nmrl.experiments.exploration2 publish --out runs/exploration2 --dest results/exploration2/runs
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

from nmrl.experiments import kit
from nmrl.paper.control_step import DELTA_0
from nmrl.runs import store
from nmrl.explore.spec import PAPER_CORR_TIME_S

ITERATION_S = 102.4  #: simulated seconds per environment in one PPO iteration (256 unrolls of 0.4 s)
SIGMAS = (0.064, 0.16, 0.4, 1.0)
SCREEN_SEED0, SCREEN_SEEDS, SCREEN_ITERATIONS = 100, 2, 4
#: the paper's alpha = 0.8 per 20 ms step as a correlation time, to the 5 digits the cells' options give
NM_CORR_TIME_S = round(PAPER_CORR_TIME_S, 5)
#: each arm's exploration options at the middle of its screened time constant
ARMS = {
    "white": ("--exploration", "white"),
    "ou": ("--exploration", "ou", "--corr-time-s", "0.03"),
    "colored": ("--exploration", "colored", "--beta", "0.5"),
    "nms": ("--exploration", "nm-periods", "--period-s", "0.06", "--corr-time-s", str(NM_CORR_TIME_S)),
    "nmp": ("--exploration", "nm-periods", "--period-s", "0.06", "--corr-time-s", str(NM_CORR_TIME_S),
            "--period-wise", "true"),
}


def base(dt: float, iterations: int) -> tuple[str, ...]:
    """The options every cell at control step ``dt`` shares (module docstring)."""
    steps = round(iterations * ITERATION_S / dt)
    return ("--learner", "ppo", "--num-envs", "64", "--value-layers", "2", "--value-width", "64",
            "--batch-size", "512", "--num-minibatches", "32", "--epochs", "8", "--reward-scale", f"{dt / DELTA_0:g}",
            "--control-dt", f"{dt:g}", "--trial-s", "5", "--physics", "c", "--physics-timestep", "0.0025",
            "--steps", str(steps))


def sigma_cell(arm: str, dt: float) -> kit.Cell:
    return kit.Cell(f"screen/sigma/dt{dt:g}/{arm}",
                    (*base(dt, SCREEN_ITERATIONS), *ARMS[arm], "--vary", "sigma", *map(str, SIGMAS),
                     "--seeds", str(SCREEN_SEEDS), "--seed0", str(SCREEN_SEED0)))


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


def _finished(rows: list[dict], prefix: str) -> list[dict] | None:
    """The rows of the cells named ``prefix`` or ``prefix+...`` when every point is at its budget and
    scored; None while any is not."""
    mine = [r for r in rows if r["cell"] == prefix or r["cell"].startswith(prefix + "+")]
    if not mine or not all(_ended(r) for r in mine):
        return None
    return mine


def _ended(r: dict) -> bool:
    """Whether a run's row is final: at its budget, or diverged (frozen at its last good policy),
    and scored."""
    return (int(r["steps"]) == int(r["budget"]) or str(r["diverged"]) == "True") and r["det_reward_per_s"] != ""


def choose(rows: list[dict]) -> tuple[float, bool, list[float]] | None:
    """``(best value, at an edge, the values screened)`` of finished screen rows: the value whose
    seeds' mean deterministic reward per second is highest; a value with a diverged run is never
    chosen (None if every value has one)."""
    by: dict[float, list[dict]] = {}
    for r in rows:
        by.setdefault(float(r["value"]), []).append(r)
    ok = {v: sum(float(r["det_reward_per_s"]) for r in rs) / len(rs) for v, rs in by.items()
          if not any(str(r["diverged"]) == "True" for r in rs)}
    if not ok:
        return None
    best = max(ok, key=ok.get)
    values = sorted(by)
    return best, best in (values[0], values[-1]), values


def _extension(cell: kit.Cell, rows: list[dict], factor: float) -> kit.Cell | None:
    """The next value beyond the edge the winner sits at (``cell`` with that one value), if allowed."""
    got = choose(rows)
    if got is None:
        return None
    best, edge, values = got
    n_ext = len({r["cell"] for r in rows if r["cell"].startswith(cell.name + "+")})
    if not edge or n_ext >= MAX_EXTENSIONS:
        return None
    nxt = best * factor if best == values[-1] else best / factor
    argv = list(cell.sweep)
    i = argv.index("--vary")
    j = i + 2
    while j < len(argv) and not argv[j].startswith("--"):
        j += 1
    argv[i + 2:j] = [f"{nxt:.6g}"]
    return kit.Cell(f"{cell.name}+{nxt:.6g}", tuple(argv))


def _screen(rows: list[dict], cell: kit.Cell) -> tuple[list[kit.Cell], dict | None]:
    """One sigma-screen cell's rule (docs/exploration-study-2.md): the cells it adds so far (a sigma
    winner at an edge adds the next sigma, x or / 2.5, at most twice; once sigma is chosen, the
    arm's time constant's other values at that sigma, with the same edge extension by the values'
    own factor: x or / 3, beta x or / 2) and, once every one of them is finished, the choice:
    ``{"sigma": ..., <time constant field>: ...}`` (None until then)."""
    arm, dt = cell.name.split("/")[-1], float(cell.name.split("/")[2].removeprefix("dt"))
    done = _finished(rows, cell.name)
    if done is None:
        return [], None
    ext = _extension(cell, done, SIGMA_FACTOR)
    if ext is not None:
        return [ext], None
    sigma = choose(done)
    if sigma is None:
        return [], None
    if arm not in TIME_CONSTANTS:
        return [], {"sigma": sigma[0]}
    field, vals, factor = TIME_CONSTANTS[arm]
    options = list(ARMS[arm])
    k = options.index("--" + field.replace("_", "-"))
    del options[k:k + 2]  # the field is varied instead
    tc = kit.Cell(f"screen/tc/dt{dt:g}/{arm}",
                  (*base(dt, SCREEN_ITERATIONS), *options, "--sigma", f"{sigma[0]:.6g}",
                   "--vary", field, f"{vals[0]:g}", f"{vals[2]:g}",
                   "--seeds", str(SCREEN_SEEDS), "--seed0", str(SCREEN_SEED0)))
    tc_rows = _finished(rows, tc.name)
    if tc_rows is None:
        return [tc], None
    at_sigma = [dict(r, value=vals[1]) for r in done if float(r["value"]) == sigma[0]]
    ext = _extension(tc, tc_rows + at_sigma, factor)
    if ext is not None:
        return [tc, ext], None
    best = choose(tc_rows + at_sigma)
    return [tc], None if best is None else {"sigma": sigma[0], field: best[0]}


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


def grid_cell(arm: str, dt: float, choice: dict, seeds: int, name: str | None = None,
              iterations: int = GRID_ITERATIONS) -> kit.Cell:
    """``arm`` at ``dt`` with its chosen sigma and time constant, seeds 0.. at the full budget
    (``iterations``: the grid's 16 unless given)."""
    options = list(ARMS["white" if arm == "ws" else arm])
    for field, value in choice.items():
        flag = "--" + field.replace("_", "-")
        if flag in options:
            options[options.index(flag) + 1] = f"{value:.6g}"
        else:
            options += [flag, f"{value:.6g}"]
    return kit.Cell(name or f"grid/dt{dt:g}/{arm}",
                    (*base(dt, iterations), *options, "--seeds", str(seeds), "--seed0", "0"))


def later_cells(rows: list[dict]) -> list[kit.Cell]:
    """The cells the rows so far call for, in run order (docs/exploration-study-2.md): the screen's
    extensions and time constants; once every primary setting is chosen, the primary grid (W and NMp
    at 20 ms, W, Ws, OU, CN, NMs and NMp at 2.5 ms, 8 seeds, 16 iterations), then the secondary
    parts: the 5 ms column (W and NMp with the 2.5 ms choices, Ws by eq. (1)), OU, CN and NMs at
    20 ms with their own screens, 4 seeds each, and W's sigma sensitivity at 2.5 ms (one screen step
    either side of its choice). A Ws sigma above nmrl's range (10) is not run (reported)."""
    out: list[kit.Cell] = []
    chosen: dict[tuple[str, float], dict] = {}
    for cell in SIGMA_SCREEN:
        add, ch = _screen(rows, cell)
        out += add
        if ch is not None:
            chosen[(cell.name.split("/")[-1], float(cell.name.split("/")[2].removeprefix("dt")))] = ch
    if any(key not in chosen for key in PRIMARY):
        return out
    s20 = chosen[("white", 0.02)]["sigma"]
    for arm, dt in PRIMARY:
        out.append(grid_cell(arm, dt, chosen[(arm, dt)], GRID_SEEDS))
        if arm == "white" and dt != 0.02 and scaled_white_sigma(s20, dt) <= SIGMA_MAX:  # at 20 ms Ws is W
            out.append(grid_cell("ws", dt, {"sigma": scaled_white_sigma(s20, dt)}, GRID_SEEDS))
    for arm in ("white", "ws", "nmp"):  # the 5 ms column takes the 2.5 ms choices
        ch = {"sigma": scaled_white_sigma(s20, 0.005)} if arm == "ws" else chosen[(arm, 0.0025)]
        if ch["sigma"] <= SIGMA_MAX:
            out.append(grid_cell(arm, 0.005, ch, SECONDARY_SEEDS))
    for cell in SECONDARY_SCREEN:
        add, ch = _screen(rows, cell)
        out += [cell, *add]
        if ch is not None:
            out.append(grid_cell(cell.name.split("/")[-1], 0.02, ch, SECONDARY_SEEDS))
    sw = chosen[("white", 0.0025)]["sigma"]
    for s in (sw / SIGMA_FACTOR, sw * SIGMA_FACTOR):
        if s <= SIGMA_MAX:
            out.append(grid_cell("white", 0.0025, {"sigma": s}, SECONDARY_SEEDS,
                                 name=f"sensitivity/dt0.0025/white_sigma{s:.6g}"))
    best = best_correlated(rows)
    if best is not None:
        for arm in ("white", best):
            out.append(grid_cell(arm, 0.005, chosen[(arm, 0.0025)], SECONDARY_SEEDS,
                                 name=_a(arm), iterations=ASYMPTOTE_ITERATIONS))
    for it in SNR_POLICY_ITERATIONS:  # white's 20 ms policies for the SNR at matched policies
        out.append(grid_cell("white", 0.02, chosen[("white", 0.02)], SNR_SEEDS, name=_snr(it), iterations=it))
    return out


SNR_SEEDS = 3  #: seeds of the matched policies (0-2: the grid's white at 20 ms holds their iteration 16)
SNR_POLICY_ITERATIONS = (1, 4, 8)  #: iteration 1's point gives iteration 0's observation statistics
SNR_CSV = "snr.csv"


def _snr(it: int) -> str:
    return f"snr/dt0.02/white_it{it}"


def snr(out: pathlib.Path, rows: list[dict]) -> None:
    """The gradient's SNR at matched policies (nmrl/experiments/matched_snr.py) into ``snr.csv``:
    white's 20 ms policies of seeds 0-2 after 0, 4, 8 and 16 iterations, at 20, 5 and 2.5 ms, with
    white at their own sigma and NMp with its chosen settings at each control step (20 ms: its 20 ms
    choice; 5 and 2.5 ms: its 2.5 ms one). Waits until those cells are complete."""
    from nmrl.experiments import matched_snr

    cells = _complete_cells(rows)
    need = [_snr(it) for it in SNR_POLICY_ITERATIONS] + [_g("white", 0.02), _g("nmp", 0.02), _g("nmp", 0.0025)]
    if any(c not in cells for c in need):
        return

    def points(cell: str) -> dict[int, pathlib.Path]:
        return {int(r["seed"]): out / cell / "points" / r["point"] for r in rows
                if r["cell"] == cell and int(r["seed"]) < SNR_SEEDS}

    def config(cell: str) -> dict:
        return json.loads((next(iter(points(cell).values())) / "config.json").read_text())

    by_it = {0: points(_snr(1)), 4: points(_snr(4)), 8: points(_snr(8)), 16: points(_g("white", 0.02))}
    white = matched_snr.exploration_of(config(_g("white", 0.02)))
    nmp20, nmp_fine = (matched_snr.exploration_of(config(_g("nmp", dt))) for dt in (0.02, 0.0025))
    arms = {"white": {dt: white for dt in matched_snr.DTS},
            "nmp": {dt: nmp20 if dt == 0.02 else nmp_fine for dt in matched_snr.DTS}}
    matched_snr.measure(by_it, arms, out / SNR_CSV)


CORRELATED = ("ou", "colored", "nms", "nmp")
ASYMPTOTE_ITERATIONS = 4 * GRID_ITERATIONS  #: the asymptote's budget: 4x the grid's, at 5 ms


def _a(arm: str) -> str:
    return f"asymptote/dt0.005/{arm}"


def best_correlated(rows: list[dict]) -> str | None:
    """The correlated arm (OU, CN, NMs, NMp) whose 2.5 ms grid cell has the highest mean
    deterministic reward per second, once all four cells are complete (None before): the arm the
    asymptote runs against white."""
    cells = _complete_cells(rows)
    means = {arm: sum(cells[_g(arm, 0.0025)]) / len(cells[_g(arm, 0.0025)]) for arm in CORRELATED
             if _g(arm, 0.0025) in cells}
    return max(means, key=means.get) if len(means) == len(CORRELATED) else None


MARGIN = 50.0  #: the TOST margin of "no difference" [reward/s]


def _g(arm: str, dt: float) -> str:
    return f"grid/dt{dt:g}/{arm}"


#: the primary family P1-P7 (docs/exploration-study-2.md), contrasts of the grid cells' endpoints
CONTRASTS = (
    ("P1", {_g("white", 0.0025): 1.0, _g("white", 0.02): -1.0}),
    ("P2", {_g("ws", 0.0025): 1.0, _g("white", 0.0025): -1.0}),
    ("P3", {_g("ou", 0.0025): 1.0, _g("white", 0.0025): -1.0}),
    ("P4", {_g("colored", 0.0025): 1.0, _g("white", 0.0025): -1.0}),
    ("P5", {_g("nms", 0.0025): 1.0, _g("white", 0.0025): -1.0}),
    ("P6", {_g("nmp", 0.0025): 1.0, _g("white", 0.0025): -1.0}),
    ("P7", {_g("nmp", 0.0025): 1.0, _g("nmp", 0.02): -1.0, _g("white", 0.0025): -1.0, _g("white", 0.02): 1.0}),
)


#: the secondary family (Holm apart from the primary): the 5 ms column against 20 ms, and the
#: interactions like P7 of OU, CN and NMs screened at 20 ms
SECONDARY = (
    ("S1", {_g("white", 0.005): 1.0, _g("white", 0.02): -1.0}),
    ("S2", {_g("ws", 0.005): 1.0, _g("white", 0.005): -1.0}),
    ("S3", {_g("nmp", 0.005): 1.0, _g("white", 0.005): -1.0}),
    ("S4", {_g("nmp", 0.005): 1.0, _g("nmp", 0.02): -1.0, _g("white", 0.005): -1.0, _g("white", 0.02): 1.0}),
    *((f"S{5 + i}", {_g(arm, 0.0025): 1.0, _g(arm, 0.02): -1.0, _g("white", 0.0025): -1.0, _g("white", 0.02): 1.0})
      for i, arm in enumerate(("ou", "colored", "nms"))),
)


def _complete_cells(rows: list[dict]) -> dict[str, list[float]]:
    """The deterministic endpoints of every cell whose runs all ended (at the budget, or diverged
    and scored by their last good policy) and were scored; a cell with a run still going is left
    out (its contrasts stay pending)."""
    by: dict[str, list[dict]] = {}
    for r in rows:
        if not r["cell"].startswith("screen/"):
            by.setdefault(r["cell"], []).append(r)
    return {c: [float(r["det_reward_per_s"]) for r in rs] for c, rs in by.items() if all(_ended(r) for r in rs)}


def _reported(name: str, weights: dict[str, float], cells: dict[str, list[float]]) -> dict:
    """One contrast with its 95% Welch interval, no decision (a check that decides nothing)."""
    from nmrl.analysis import prereg_stats

    row = {"family": "check", "contrast": name, "cells": " ".join(f"{w:+g}*{c}" for c, w in weights.items())}
    try:
        r = prereg_stats.contrast([cells[c] for c in weights], list(weights.values()))
    except (KeyError, ValueError):
        return {**row, "decision": "pending"}
    return {**row, "n": " ".join(str(len(cells[c])) for c in weights), "estimate": r.diff, "lo": r.lo,
            "hi": r.hi, "p": r.p, "decision": "reported"}


def analysis(rows: list[dict]) -> list[dict]:
    """The primary family P1-P7 on the deterministic endpoint (reward per second) of the complete
    grid cells: Welch contrasts, Holm over P1-P7, TOST at +-50 (nmrl.analysis.prereg_stats.family);
    the secondary family S1-S7 the same way, Holm apart; and two checks that decide nothing, each
    with its Welch interval: W's sigma sensitivity at 2.5 ms (each neighbouring sigma minus the grid's
    W) and the asymptote at 5 ms (the best correlated arm minus white at 4x the budget)."""
    from nmrl.analysis import prereg_stats

    cells = _complete_cells(rows)
    out = [{"family": "primary", **r} for r in prereg_stats.family(cells, CONTRASTS, MARGIN)]
    out += [{"family": "secondary", **r} for r in prereg_stats.family(cells, SECONDARY, MARGIN)]
    for c in sorted(c for c in cells if c.startswith("sensitivity/")):
        out.append(_reported(c.split("/")[-1], {c: 1.0, _g("white", 0.0025): -1.0}, cells))
    best = best_correlated(rows)
    if best is not None:
        out.append(_reported("asymptote", {_a(best): 1.0, _a("white"): -1.0}, cells))
    return out


CELLS_CSV = "cells.csv"
SCREEN_FIGURE, GRID_FIGURE = "screen_curves.png", "learning_curves.png"
CELL_COLUMNS = ("cell", "value", "n", "mean", "sd", "ci_lo", "ci_hi", "iqm", "iqm_lo", "iqm_hi")


def _curve(point: pathlib.Path) -> tuple[np.ndarray, np.ndarray]:
    """A point's learning curve: simulated seconds per environment, exploring reward per second."""
    cfg = json.loads((point / "config.json").read_text())
    m = store.read_metrics(point)
    return (np.array([r["step"] * cfg["control_dt"] for r in m]),
            np.array([r["avg_reward"] / DELTA_0 for r in m]))


def report(rows: list[dict], dest: pathlib.Path) -> None:
    """``cells.csv`` (every cell's and screened value's deterministic endpoint at its budget:
    nmrl.analysis.cell_curves.summary), the screen's learning curves (one panel per screened arm and
    control step, one line per value, extensions included) and, once grid cells exist, the grid's
    (one panel per control step, one line per arm), from the published points' metrics."""
    from nmrl.analysis import cell_curves

    groups: dict[tuple[str, str], list[float]] = {}
    screen: dict[str, dict[str, list]] = {}
    grid: dict[str, dict[str, list]] = {}
    for r in rows:
        key = (r["cell"], f"{float(r['value']):g}" if r["cell"].startswith("screen/") else "")
        at_budget = int(r["steps"]) == int(r["budget"]) and r["det_reward_per_s"] != ""
        groups.setdefault(key, []).extend([float(r["det_reward_per_s"])] if at_budget else [])
        point = dest / r["cell"] / "points" / r["point"]
        if not (point / "metrics.jsonl").is_file():
            continue
        base_name = r["cell"].split("+")[0]
        if r["cell"].startswith("screen/"):
            field = r["field"].replace("_", " ")
            screen.setdefault(base_name.removeprefix("screen/"), {}).setdefault(f"{field} {key[1]}", []).append(
                _curve(point))
        elif r["cell"].startswith("grid/"):
            _, dt, arm = r["cell"].split("/")
            grid.setdefault(f"control step {float(dt[2:]) * 1000:g} ms", {}).setdefault(arm, []).append(_curve(point))
    store.write_csv(dest / CELLS_CSV, CELL_COLUMNS,
                   [{"cell": c, "value": v, **cell_curves.summary(x)} for (c, v), x in groups.items()])
    if screen:
        cell_curves.figure(screen, dest / SCREEN_FIGURE, "exploring reward per second", "the screen (seeds 100, 101)")
    if grid:
        cell_curves.figure(grid, dest / GRID_FIGURE, "exploring reward per second", "the grid")
    if (dest / SNR_CSV).is_file():
        _snr_report(dest)


SNR_SUMMARY_CSV, SNR_FIGURE = "snr_summary.csv", "snr.png"


def _snr_report(dest: pathlib.Path) -> None:
    """``snr_summary.csv``: per arm, iteration and control step, the SNR per second over the seeds'
    policies (cell_curves.summary: mean, 95% t interval); ``snr.png``: one panel per arm, the mean
    against the control step, one line per iteration, with the t intervals."""
    from nmrl.analysis import cell_curves, plots

    got = store.read_csv(dest / SNR_CSV)
    groups: dict[tuple[str, int, float], list[float]] = {}
    for r in got:
        groups.setdefault((r["arm"], int(r["iteration"]), float(r["control_dt"])), []).append(float(r["snr_per_s"]))
    table = [{"arm": a, "iteration": it, "control_dt": dt, **cell_curves.summary(x)}
             for (a, it, dt), x in sorted(groups.items())]
    store.write_csv(dest / SNR_SUMMARY_CSV, ("arm", "iteration", "control_dt", *CELL_COLUMNS[2:]), table)
    arms = sorted({a for a, _, _ in groups})
    fig, axes = plots.plt.subplots(1, len(arms), figsize=(4.6 * len(arms), 3.6), sharey=True, squeeze=False,
                                   layout="constrained")
    for ax, arm in zip(axes[0], arms):
        for it in sorted({i for a, i, _ in groups if a == arm}):
            rs = [r for r in table if r["arm"] == arm and r["iteration"] == it]
            dt_ms = [1000 * r["control_dt"] for r in rs]
            mean = [r["mean"] for r in rs]
            err = [[m - (r["ci_lo"] if r["ci_lo"] != "" else m) for m, r in zip(mean, rs)],
                   [(r["ci_hi"] if r["ci_hi"] != "" else m) - m for m, r in zip(mean, rs)]]
            ax.errorbar(dt_ms, mean, yerr=err, marker="o", capsize=3, label=f"iteration {it}")
        ax.set_xscale("log")
        ax.set_title(arm)
        ax.set_xlabel("control step [ms]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("gradient SNR per second of experience")
    plots.save(fig, dest / SNR_FIGURE, dpi=110, bbox_inches="tight")


STUDY = kit.Study(name="exploration2", cells=SIGMA_SCREEN, endpoint=kit.Endpoint(seconds=10.0, rollouts=8,
                                                                                 start_noise=0.05, seed=0),
                  later=later_cells, analysis=analysis, report=report,
                  measurements=(kit.Measurement(SNR_CSV, snr),))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m nmrl.experiments.exploration2", description=__doc__.split("\n\n")[0])
    ap.add_argument("action", choices=("run", "publish", "rows"))
    ap.add_argument("--out", required=True, help="the study's run directory")
    ap.add_argument("--published", default=None, help="a published copy: cells missing in --out start from it")
    ap.add_argument("--dest", default=None, help="publish: where the copy goes")
    ap.add_argument("--only", nargs="*", default=(), help="cells whose names start with one of these")
    a = ap.parse_args(argv)
    if a.action == "run":
        try:
            kit.run(STUDY, a.out, published=a.published, only=a.only)
        except kit.StudyStopped as e:
            print(f"exploration2: {e}; run again to continue", file=sys.stderr)
            return e.status
    elif a.action == "publish":
        if not a.dest:
            ap.error("publish needs --dest")
        kit.publish(STUDY, a.out, a.dest)
    else:
        kit.write_rows(STUDY, pathlib.Path(a.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
