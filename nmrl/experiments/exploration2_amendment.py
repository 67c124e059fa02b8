"""Study 2's amendment A (docs/exploration-study-2.md, "Amendment A") on the kit: P6, P7 and P1
again at 32 PPO iterations, with NMp(20) against W(20) and P1 with the trust region per second
held; its cells, rule, family and command.

    python -m nmrl.experiments.exploration2_amendment run --out runs/exploration2_amendment \\
        [--published results/exploration2/amendment]
    python -m nmrl.experiments.exploration2_amendment publish --out runs/exploration2_amendment \\
        --dest results/exploration2/amendment

The cells are the grid's (nmrl/experiments/exploration2_cells.py: ``grid_cell`` with each grid
cell's own settings, layout and options) at twice its budget, so that each run's first 16
iterations are the grid's run; W at 2.5 ms with the clip per step scaled by sqrt(2.5 / 20)
(:data:`WC_CLIP`); the sigma check at 20 ms. NMp at 2.5 ms runs only when NMp(20) walks in at least
:data:`WALK_RULE` of its 8 runs (:func:`later`). The family A1-A5: two-sided Welch on the
deterministic endpoint, Holm over the contrasts that ran, TOST at +-50 reward per second with Holm
over the same; the sigma check reported with Welch intervals, deciding nothing.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import sys

import numpy as np

from nmrl.experiments import kit, kit_cli, kit_gaits
from nmrl.experiments.exploration2_cells import ARMS, ENDPOINT, GRID_SEEDS, cell, grid_cell
from nmrl.runs import store

ITERATIONS = 32  #: twice the grid's 16
#: each arm's grid settings at each control step (the screen's choices; tests check them against
#: the published grid's config.json)
CHOICES = {("white", 0.02): {"sigma": 1.0}, ("nmp", 0.02): {"sigma": 1.0},
           ("white", 0.0025): {"sigma": 1.0}, ("nmp", 0.0025): {"sigma": 1.0, "period_s": 0.02}}
#: Wc(2.5)'s clip per step: 0.3 sqrt(2.5 / 20), so that a clipped ratio's KL per second (KL per step
#: ~ eps^2, over delta) equals W(20)'s
WC_CLIP = 0.3 * math.sqrt(0.0025 / 0.02)
SIGMA_CHECK = (0.4, 2.5)
SIGMA_SEEDS = 4
WALK_SPEED, WALK_RULE = 1.0, 5  #: a run walks at >= 1 m/s deterministic; NMp(2.5) runs if >= 5 of 8 NMp(20) do
MARGIN = 50.0  #: reward per second (the primary family's)


def _name(arm: str, dt: float) -> str:
    return f"amendment/dt{dt:g}/{arm}"


def family_cell(arm: str, dt: float) -> kit.Cell:
    """``arm``'s grid cell at ``dt`` (its name, options and layout) carried to :data:`ITERATIONS`."""
    cell = grid_cell(arm, dt, CHOICES[(arm, dt)], GRID_SEEDS, iterations=ITERATIONS)
    return dataclasses.replace(cell, name=_name(arm, dt))


def wc_cell() -> kit.Cell:
    """W(2.5)'s cell with the clip :data:`WC_CLIP`."""
    cell = family_cell("white", 0.0025)
    return dataclasses.replace(cell, name=_name("wc", 0.0025),
                               settings={**cell.settings, "clip_eps": float(f"{WC_CLIP:.6g}")})


def sigma_cell(arm: str) -> kit.Cell:
    """``arm`` at 20 ms with sigma :data:`SIGMA_CHECK`, seeds 0-3, :data:`ITERATIONS` (a seed at a
    time, as its family cell)."""
    return cell(f"amendment/sigma/dt0.02/{arm}", 0.02, ITERATIONS, ARMS[arm], vary=("sigma", SIGMA_CHECK),
                seeds=SIGMA_SEEDS, seed0=0)


CELLS = (family_cell("nmp", 0.02), family_cell("white", 0.02), sigma_cell("white"), sigma_cell("nmp"),
         family_cell("white", 0.0025))


def _cell_rows(rows: list[dict], name: str) -> list[dict] | None:
    """The rows of cell ``name`` once every point of it has ended, else None."""
    rs = [r for r in rows if r["cell"] == name]
    return rs if rs and all(kit.ended(r) for r in rs) else None


def walking(rs: list[dict]) -> int:
    """How many of the runs ``rs`` walk (deterministic forward speed >= :data:`WALK_SPEED`)."""
    return sum(float(r["det_forward_speed"]) >= WALK_SPEED for r in rs)


def later(rows: list[dict]) -> list[kit.Cell]:
    """After the cells above: NMp(2.5) when NMp(20) walks in >= :data:`WALK_RULE` of its runs, then Wc(2.5)."""
    nmp20 = _cell_rows(rows, _name("nmp", 0.02))
    if nmp20 is None:
        return []
    return ([family_cell("nmp", 0.0025)] if walking(nmp20) >= WALK_RULE else []) + [wc_cell()]


#: A1-A5 (the page's table): weights on cells
CONTRASTS = (
    ("A1", {_name("nmp", 0.0025): 1.0, _name("white", 0.0025): -1.0}),
    ("A2", {_name("nmp", 0.0025): 1.0, _name("nmp", 0.02): -1.0, _name("white", 0.0025): -1.0,
            _name("white", 0.02): 1.0}),
    ("A3", {_name("nmp", 0.02): 1.0, _name("white", 0.02): -1.0}),
    ("A4", {_name("white", 0.0025): 1.0, _name("white", 0.02): -1.0}),
    ("A5", {_name("wc", 0.0025): 1.0, _name("white", 0.02): -1.0}),
)


def family(rows: list[dict]) -> list[dict]:
    """A1-A5 on the deterministic endpoint (module docstring: ``prereg_stats.family``, Holm and TOST
    over the contrasts that run, the stratified bootstrap interval beside Welch's), each with how
    many runs of each of its cells walk; every decision
    "pending" until each contrast's cells have ended or, for those with NMp(2.5), the rule has left
    it out."""
    from nmrl.analysis import cell_curves, prereg_stats

    nmp20 = _cell_rows(rows, _name("nmp", 0.02))
    dropped = nmp20 is not None and walking(nmp20) < WALK_RULE  # NMp(2.5) does not run
    contrasts = [(n, w) for n, w in CONTRASTS if not (dropped and _name("nmp", 0.0025) in w)]
    ended = {c: _cell_rows(rows, c) for _, w in contrasts for c in w}
    cells = {c: [float(r["det_reward_per_s"]) for r in rs] for c, rs in ended.items() if rs is not None}
    out = prereg_stats.family(cells, contrasts, MARGIN, bootstrap_reps=cell_curves.BOOTSTRAP_REPS)
    for r, (_, weights) in zip(out, contrasts):
        if all(ended[c] is not None for c in weights):
            r.update(walking=" ".join(f"{walking(ended[c])}/{len(ended[c])}" for c in weights), margin=MARGIN)
    return out


def sigma_check(rows: list[dict]) -> list[dict]:
    """Each arm's sigma 0.4 and 2.5 at 20 ms minus its family cell's seeds 0-3 (sigma 1), with the
    Welch interval, deciding nothing."""
    from nmrl.analysis import prereg_stats

    out = []
    for arm in ("white", "nmp"):
        check, fam = _cell_rows(rows, f"amendment/sigma/dt0.02/{arm}"), _cell_rows(rows, _name(arm, 0.02))
        for s in SIGMA_CHECK:
            row = {"contrast": f"{arm}(20) sigma {s:g} - sigma 1"}
            if check is None or fam is None:
                out.append({**row, "decision": "pending"})
                continue
            a = np.array([float(r["det_reward_per_s"]) for r in check if float(r["value"]) == s])
            b = np.array([float(r["det_reward_per_s"]) for r in fam if int(r["seed"]) < SIGMA_SEEDS])
            w = prereg_stats.welch(a, b)
            out.append({**row, "n": f"{len(a)} {len(b)}", "estimate": w.diff, "lo": w.lo, "hi": w.hi, "p": w.p,
                        "decision": "beats sigma 1 by more than the margin" if w.diff > MARGIN else "reported"})
    return out


def analysis(rows: list[dict]) -> list[dict]:
    """The amended family and the sigma check, as ``analysis.csv``'s rows."""
    return [{"family": "amendment", **r} for r in family(rows)] + [{"family": "check", **r} for r in sigma_check(rows)]


#: the first edition's published runs, whose first 16 iterations each family cell's runs repeat
RECORD = pathlib.Path(__file__).resolve().parents[2] / "results" / "exploration2" / "runs"
GRID_ITERATIONS = 16
#: a metrics row's keys that time the run rather than compute it (not compared)
TIMING = ("wall_s", "steps_per_s")
FAMILY_CELLS = {_name(arm, dt): (arm, dt) for arm in ("white", "nmp") for dt in (0.02, 0.0025)}


def continuation(dest: pathlib.Path, record: pathlib.Path = RECORD) -> list[dict]:
    """The page's check that each family cell's run repeats the grid's: per published point with at
    least :data:`GRID_ITERATIONS` iterations, its first 16 metrics rows against the same seed's in
    the first edition's grid (every key but :data:`TIMING`), whether they are identical, the largest
    relative difference and the first key that differs."""
    out = []
    for name, (arm, dt) in FAMILY_CELLS.items():
        for point in kit.point_dirs(dest / name):
            mine = store.read_metrics(point)[:GRID_ITERATIONS]
            theirs_path = record / "grid" / f"dt{dt:g}" / arm / "points" / point.name
            if len(mine) < GRID_ITERATIONS or not (theirs_path / "metrics.jsonl").is_file():
                continue
            theirs = store.read_metrics(theirs_path)[:GRID_ITERATIONS]
            worst, first = 0.0, ""
            for a, b in zip(mine, theirs):
                for k in sorted(set(a) | set(b)):
                    if k in TIMING or a.get(k) == b.get(k):
                        continue
                    first = first or f"{k} at iteration {a.get('chunk')}"
                    x, y = a.get(k), b.get(k)
                    num = isinstance(x, (int, float)) and isinstance(y, (int, float))
                    worst = max(worst, abs(x - y) / max(abs(x), abs(y)) if num else math.inf)
            out.append({"cell": name, "point": point.name, "iterations": len(theirs), "identical": first == "",
                        "max_rel_diff": worst, "first_difference": first})
    return out




CONTINUATION_CSV, CELLS_CSV = "continuation.csv", "cells.csv"
LEARNING_FIGURE, ENDPOINT_FIGURE, CONTRAST_FIGURE = "learning_curves.png", "endpoints.png", "contrasts.png"


def _label(cell_name: str) -> tuple[str, str]:
    """(panel, line) of an amendment cell: ``amendment/dt0.0025/wc`` -> control step 2.5 ms, wc."""
    _, dt, arm = cell_name.split("/")
    return f"control step {float(dt[2:]) * 1000:g} ms", arm


def report(rows: list[dict], dest: pathlib.Path) -> None:
    """``continuation.csv`` (:func:`continuation`); ``cells.csv``: per ended family cell and Wc(2.5),
    its runs' deterministic endpoint (``cell_curves.summary``) and how many walk; the learning curves
    over 32 iterations (a panel per control step, a line per arm, seed bands); every ended run's
    deterministic endpoint with its cell's interval; the family against its margin once it has
    estimates; all from the published points alone."""
    from nmrl.analysis import cell_curves, contrast_figures

    store.write_csv(dest / CONTINUATION_CSV, ("cell", "point", "iterations", "identical", "max_rel_diff",
                                              "first_difference"), continuation(dest))
    names = [*FAMILY_CELLS, _name("wc", 0.0025)]
    summaries, curves, det = [], {}, {}
    for name in names:
        for p in kit.point_dirs(dest / name):
            if (p / "metrics.jsonl").is_file():
                panel, arm = _label(name)
                curves.setdefault(panel, {}).setdefault(arm, []).append(kit.learning_curve(p))
        rs = _cell_rows(rows, name)
        if rs is not None:
            x = [float(r["det_reward_per_s"]) for r in rs]
            summaries.append({"cell": name, **cell_curves.summary(x), "walking": walking(rs)})
            panel, arm = _label(name)
            det.setdefault(panel, {})[arm] = x
    store.write_csv(dest / CELLS_CSV, ("cell", *cell_curves.SUMMARY_COLUMNS, "walking"), summaries)
    if curves:
        cell_curves.figure(curves, dest / LEARNING_FIGURE, "exploring reward per second",
                           f"amendment A: {ITERATIONS} PPO iterations")
    if det:
        contrast_figures.endpoints(det, dest / ENDPOINT_FIGURE, "deterministic reward per second",
                                   "every ended run, each cell's mean and 95% t interval")
    table = [r for r in family(rows) if r.get("estimate", "") != ""]
    if table:
        contrast_figures.contrasts(table, MARGIN, dest / CONTRAST_FIGURE,
                                   "difference of the deterministic endpoint, reward per second (95% Welch interval)",
                                   "amendment A's family")


GAIT_DT = 0.0025


def gait_picks(rows: list[dict]) -> list[dict] | None:
    """The best and the worst arm at 2.5 ms by their cell's mean deterministic endpoint, among the
    2.5 ms cells that run (W, Wc and, when the rule runs it, NMp), each its median run
    (``kit_gaits.median_run``); None until every one of them has ended."""
    nmp20 = _cell_rows(rows, _name("nmp", 0.02))
    if nmp20 is None:
        return None
    arms = ["white", "wc"] + (["nmp"] if walking(nmp20) >= WALK_RULE else [])
    ended = {a: _cell_rows(rows, _name(a, GAIT_DT)) for a in arms}
    if any(rs is None for rs in ended.values()):
        return None
    means = {a: float(np.mean([float(r["det_reward_per_s"]) for r in rs])) for a, rs in ended.items()}
    order = sorted(arms, key=lambda a: means[a])
    return [kit_gaits.pick(ended[arm], name=f"{rank}_{arm}", rank=rank, arm=arm, cell=_name(arm, GAIT_DT),
                           cell_mean=means[arm]) for rank, arm in (("best", order[-1]), ("worst", order[0]))]


def gaits(out: pathlib.Path, rows: list[dict]) -> None:
    """The gaits of :func:`gait_picks` (nmrl/experiments/kit_gaits.py), once they are known."""
    picks = gait_picks(rows)
    if picks is not None:
        kit_gaits.draw(out, picks, lambda c: f"{c['arm']} at 2.5 ms, {ITERATIONS} iterations (the {c['rank']} arm), "
                                             f"seed {c['seed']}, deterministic policy")


STUDY = kit.Study(name="exploration2_amendment", cells=CELLS, endpoint=ENDPOINT, later=later, analysis=analysis,
                  report=report, measurements=(kit.Measurement(kit_gaits.GAITS, gaits),))


def main(argv: list[str] | None = None) -> int:
    return kit_cli.main(STUDY, argv, "python -m nmrl.experiments.exploration2_amendment", __doc__.split("\n\n")[0])


if __name__ == "__main__":
    sys.exit(main())
