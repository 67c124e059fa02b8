"""The second exploration study's analysis and report (docs/exploration-study-2.md), from its rows.

:func:`analysis`: the pre-registered families on the deterministic endpoint of the complete grid
cells (Welch contrasts, Holm, TOST; nmrl/analysis/prereg_stats.py) and the checks that decide
nothing; :func:`secondary_endpoints`: the same contrasts on the secondary endpoints, reported;
:func:`arm_iqms`: each arm's IQM across its control steps; :func:`noise_contrasts`: the contrasts
on the policies with their noise scaled. :func:`report`: ``cells.csv``, those
tables, the screen's and the grid's learning curves and the SNR's summary, from the published
points.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from nmrl.experiments import kit
from nmrl.experiments.exploration2_cells import (ARM_COLORS, ARM_ORDER, SNR_CSV, arm_and_dt, asymptote_name,
                                                 grid_name)
from nmrl.experiments.exploration2_noise import NOISE_CSV
from nmrl.experiments.exploration2_noise import figure as noise_figure
from nmrl.experiments.exploration2_rules import (CHOICE_COLUMNS, best_correlated, choices, complete_cells, diverged,
                                                ended)
from nmrl.runs import store

MARGIN = 50.0  #: the TOST margin of "no difference" [reward/s]
#: the primary family P1-P7 (docs/exploration-study-2.md), contrasts of the grid cells' endpoints
CONTRASTS = (
    ("P1", {grid_name("white", 0.0025): 1.0, grid_name("white", 0.02): -1.0}),
    ("P2", {grid_name("ws", 0.0025): 1.0, grid_name("white", 0.0025): -1.0}),
    ("P3", {grid_name("ou", 0.0025): 1.0, grid_name("white", 0.0025): -1.0}),
    ("P4", {grid_name("colored", 0.0025): 1.0, grid_name("white", 0.0025): -1.0}),
    ("P5", {grid_name("nms", 0.0025): 1.0, grid_name("white", 0.0025): -1.0}),
    ("P6", {grid_name("nmp", 0.0025): 1.0, grid_name("white", 0.0025): -1.0}),
    ("P7", {grid_name("nmp", 0.0025): 1.0, grid_name("nmp", 0.02): -1.0,
            grid_name("white", 0.0025): -1.0, grid_name("white", 0.02): 1.0}),
)


#: the secondary family (Holm apart from the primary): the 5 ms column against 20 ms, and the
#: interactions like P7 of OU, CN and NMs screened at 20 ms
SECONDARY = (
    ("S1", {grid_name("white", 0.005): 1.0, grid_name("white", 0.02): -1.0}),
    ("S2", {grid_name("ws", 0.005): 1.0, grid_name("white", 0.005): -1.0}),
    ("S3", {grid_name("nmp", 0.005): 1.0, grid_name("white", 0.005): -1.0}),
    ("S4", {grid_name("nmp", 0.005): 1.0, grid_name("nmp", 0.02): -1.0,
            grid_name("white", 0.005): -1.0, grid_name("white", 0.02): 1.0}),
    *((f"S{5 + i}", {grid_name(arm, 0.0025): 1.0, grid_name(arm, 0.02): -1.0,
                     grid_name("white", 0.0025): -1.0, grid_name("white", 0.02): 1.0})
      for i, arm in enumerate(("ou", "colored", "nms"))),
)


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


#: the secondary endpoints (docs/exploration-study-2.md, "Endpoints"), in rows.csv's columns
SECONDARY_ENDPOINTS = ("avg_reward_per_s", "auc_reward_per_s", "det_forward_speed")
SECONDARY_COLUMNS = ("endpoint", "contrast", "cells", "n", "estimate", "lo", "hi", "p", "decision")


def secondary_endpoints(rows: list[dict]) -> list[dict]:
    """Every contrast of the primary and the secondary family on each secondary endpoint — the
    exploring policy's reward per second over the last iteration, its mean over the run (the area
    under the learning curve) and the deterministic forward speed [m/s] — with its estimate, 95%
    Welch interval and raw p: reported, deciding nothing (no Holm, no TOST), "pending" while one of
    its cells has a run still going. A value a run lacks (a non-finite one) is left out of its cell."""
    out = []
    for key in SECONDARY_ENDPOINTS:
        cells = {c: [v for v in x if np.isfinite(v)] for c, x in complete_cells(rows, key).items()}
        out += [{"endpoint": key, **{k: v for k, v in _reported(name, w, cells).items() if k != "family"}}
                for name, w in (*CONTRASTS, *SECONDARY)]
    return out


NOISE_CONTRASTS_CSV = "noise_contrasts.csv"
NOISE_CONTRAST_COLUMNS = ("noise_scale", "contrast", "cells", "n", "estimate", "lo", "hi", "p", "decision")


def noise_contrasts(rows: list[dict], noise_rows: list[dict]) -> list[dict]:
    """Every contrast of both families on the reward per second of the grid policies with their own
    noise times k, for each k > 0 of ``noise_rows`` (nmrl/experiments/exploration2_noise.py's table):
    estimate, 95% Welch interval and raw p, reported, deciding nothing (a check added after the
    grid's first cells); "pending" while a cell has a run going or a run not measured at k."""
    complete = complete_cells(rows)
    out = []
    for k in sorted({float(r["noise_scale"]) for r in noise_rows} - {0.0}):
        cells = {}
        for c in complete:
            runs = sorted(r["point"] for r in rows if r["cell"] == c)
            got = {r["point"]: float(r["reward_per_s"]) for r in noise_rows
                   if r["cell"] == c and float(r["noise_scale"]) == k}
            if runs and set(runs) <= set(got):
                cells[c] = [got[p] for p in runs]
        out += [{"noise_scale": k, **{f: v for f, v in _reported(name, w, cells).items() if f != "family"}}
                for name, w in (*CONTRASTS, *SECONDARY)]
    return out


ARM_COLUMNS = ("arm", "control_dts", "n", "iqm", "iqm_lo", "iqm_hi")


def arm_iqms(rows: list[dict]) -> list[dict]:
    """Per arm, the IQM of its runs' deterministic endpoints pooled over its complete grid cells at
    every control step (rliable's aggregate IQM, each cell a stratum) with the stratified percentile
    bootstrap interval (50,000 replicates, seed 0; prereg_stats.stratified_bootstrap_ci): the
    registered aggregate per arm across delta, reported, deciding nothing. ``control_dts`` and ``n``
    name the cells pooled and their finite runs, coarsest step first."""
    from nmrl.analysis import cell_curves, prereg_stats

    by: dict[str, dict[float, list[float]]] = {}
    for c, x in complete_cells(rows).items():
        finite = [v for v in x if np.isfinite(v)]
        if c.startswith("grid/") and finite:
            arm, dt = arm_and_dt(c)
            by.setdefault(arm, {})[dt] = finite
    out = []
    for arm in sorted(by, key=_arm_rank):
        dts = sorted(by[arm], reverse=True)
        strata = [by[arm][dt] for dt in dts]
        point, lo, hi = prereg_stats.stratified_bootstrap_ci(strata, reps=cell_curves.BOOTSTRAP_REPS, seed=0)
        out.append({"arm": arm, "control_dts": " ".join(f"{dt:g}" for dt in dts),
                    "n": " ".join(str(len(x)) for x in strata), "iqm": point, "iqm_lo": lo, "iqm_hi": hi})
    return out


def analysis(rows: list[dict]) -> list[dict]:
    """The primary family P1-P7 on the deterministic endpoint (reward per second) of the complete
    grid cells: Welch contrasts, Holm over P1-P7, TOST at +-50 (nmrl.analysis.prereg_stats.family);
    the secondary family S1-S7 the same way, Holm apart; and two checks that decide nothing, each
    with its Welch interval: W's sigma sensitivity at 2.5 ms (each neighbouring sigma minus the grid's
    W) and the asymptote at 5 ms (the best correlated arm minus white at 4x the budget)."""
    from nmrl.analysis import prereg_stats

    cells = complete_cells(rows)
    out = [{"family": "primary", **r} for r in prereg_stats.family(cells, CONTRASTS, MARGIN)]
    out += [{"family": "secondary", **r} for r in prereg_stats.family(cells, SECONDARY, MARGIN)]
    for c in sorted(c for c in cells if c.startswith("sensitivity/")):
        out.append(_reported(c.split("/")[-1], {c: 1.0, grid_name("white", 0.0025): -1.0}, cells))
    best = best_correlated(rows)
    if best is not None:
        out.append(_reported("asymptote", {asymptote_name(best): 1.0, asymptote_name("white"): -1.0}, cells))
    return out


CELLS_CSV, CHOICES_CSV, SECONDARY_CSV, ARMS_CSV = "cells.csv", "choices.csv", "secondary_endpoints.csv", "arms.csv"
SCREEN_FIGURE, GRID_FIGURE = "screen_curves.png", "learning_curves.png"
ENDPOINT_FIGURE, CONTRAST_FIGURE, SPEED_FIGURE = "endpoints.png", "contrasts.png", "speeds.png"
ASYMPTOTE_FIGURE, SENSITIVITY_FIGURE = "asymptote_curves.png", "sensitivity.png"


def report(rows: list[dict], dest: pathlib.Path) -> None:
    """``choices.csv`` (what the screen has decided so far: exploration2_rules.choices),
    ``cells.csv`` (every cell's and screened value's deterministic endpoint over its ended runs, a
    diverged one by its last good policy as in :func:`analysis`: nmrl.analysis.cell_curves.summary;
    with the count of its diverged runs), ``secondary_endpoints.csv`` (:func:`secondary_endpoints`),
    ``arms.csv`` (:func:`arm_iqms`),
    the screen's learning curves (one panel per screened arm and control step, one line per value,
    extensions included), once grid cells exist, the grid's (one panel per control step, one line
    per arm) and, once its runs exist, the asymptote's (``asymptote_curves.png``: white and the best
    correlated arm at 5 ms over 4x the budget), from the published points' metrics; W's sigma
    sensitivity at 2.5 ms once a neighbouring sigma's run has ended (``sensitivity.png``: every
    ended run of W at 2.5 ms by its sigma, the grid's cell among them); with them the grid's endpoints
    (``endpoints.png``: every ended run, each cell's mean and 95% t
    interval, one panel per control step), every ended grid run's forward speed with its
    exploration noise (the last iteration) against its deterministic policy's (``speeds.png``) and,
    once any contrast has an estimate, the families of :func:`analysis` against the margin
    (``contrasts.png``); with the measurements' files, the SNR's summary and figure,
    ``noise_scales.png`` (nmrl/experiments/exploration2_noise.py) and ``noise_contrasts.csv``
    (:func:`noise_contrasts`)."""
    from nmrl.analysis import cell_curves, contrast_figures

    groups: dict[tuple[str, str], list[float]] = {}
    n_diverged: dict[tuple[str, str], int] = {}
    screen: dict[str, dict[str, list]] = {}
    grid: dict[float, dict[str, list]] = {}
    asymptote: dict[str, list] = {}
    for r in rows:
        key = (r["cell"], f"{float(r['value']):g}" if r["cell"].startswith("screen/") else "")
        groups.setdefault(key, []).extend([float(r["det_reward_per_s"])] if ended(r) else [])
        n_diverged[key] = n_diverged.get(key, 0) + diverged(r)
        point = dest / r["cell"] / "points" / r["point"]
        if not (point / "metrics.jsonl").is_file():
            continue
        base_name = r["cell"].split("+")[0]
        if r["cell"].startswith("screen/"):
            field = r["field"].replace("_", " ")
            screen.setdefault(base_name.removeprefix("screen/"), {}).setdefault(f"{field} {key[1]}", []).append(
                kit.learning_curve(point))
        elif r["cell"].startswith("grid/"):
            arm, dt = arm_and_dt(r["cell"])
            grid.setdefault(dt, {}).setdefault(arm, []).append(kit.learning_curve(point))
        elif r["cell"].startswith("asymptote/"):
            asymptote.setdefault(arm_and_dt(r["cell"])[0], []).append(kit.learning_curve(point))
    store.write_csv(dest / CHOICES_CSV, CHOICE_COLUMNS, choices(rows))
    store.write_csv(dest / CELLS_CSV, ("cell", "value", *cell_curves.SUMMARY_COLUMNS, "diverged"),
                   [{"cell": c, "value": v, **cell_curves.summary(x), "diverged": n_diverged[c, v]}
                    for (c, v), x in groups.items()])
    store.write_csv(dest / SECONDARY_CSV, SECONDARY_COLUMNS, secondary_endpoints(rows))
    store.write_csv(dest / ARMS_CSV, ARM_COLUMNS, arm_iqms(rows))
    if screen:
        cell_curves.figure(screen, dest / SCREEN_FIGURE, "exploring reward per second", "the screen (seeds 100, 101)")
    if grid:
        cell_curves.figure(_panels(grid), dest / GRID_FIGURE, "exploring reward per second", "the grid", colors=ARM_COLORS)
    if asymptote:
        cell_curves.figure({"control step 5 ms, 4x the grid's budget": {a: asymptote[a] for a in
                                                                        sorted(asymptote, key=_arm_rank)}},
                           dest / ASYMPTOTE_FIGURE, "exploring reward per second", "the asymptote (seeds 0-3)",
                           colors=ARM_COLORS)
    _sensitivity_figure(groups, dest)
    by_dt: dict[float, dict[str, list[float]]] = {}
    for (c, _), x in groups.items():
        if c.startswith("grid/") and x:
            arm, dt = arm_and_dt(c)
            by_dt.setdefault(dt, {})[arm] = x
    speeds: dict[float, dict[str, list[tuple[float, float]]]] = {}
    for r in rows:
        if r["cell"].startswith("grid/") and ended(r) and r.get("forward_speed", "") != "" \
                and r.get("det_forward_speed", "") != "":
            arm, dt = arm_and_dt(r["cell"])
            speeds.setdefault(dt, {}).setdefault(arm, []).append((float(r["forward_speed"]),
                                                                  float(r["det_forward_speed"])))
    if speeds:
        contrast_figures.paired(
            _panels(speeds), dest / SPEED_FIGURE,
            "forward speed with the noise, last iteration [m/s]", "deterministic forward speed, 10 s [m/s]",
            "every ended grid run, with and without its noise", colors=ARM_COLORS)
    if by_dt:
        contrast_figures.endpoints(_panels(by_dt), dest / ENDPOINT_FIGURE, "deterministic reward per second",
                                   "the grid's primary endpoint (every ended run)", colors=ARM_COLORS)
    table = [r for r in analysis(rows) if r.get("estimate", "") != ""]
    if table:
        contrast_figures.contrasts(table, MARGIN, dest / CONTRAST_FIGURE,
                                   "difference of deterministic reward per second (95% Welch interval)",
                                   "the pre-registered contrasts (decisions: Holm over each family)")
    if (dest / SNR_CSV).is_file():
        _snr_report(dest)
    if (dest / NOISE_CSV).is_file():
        noise_figure(dest)
        store.write_csv(dest / NOISE_CONTRASTS_CSV, NOISE_CONTRAST_COLUMNS,
                        noise_contrasts(rows, store.read_csv(dest / NOISE_CSV)))


def _sensitivity_figure(groups: dict[tuple[str, str], list[float]], dest: pathlib.Path) -> None:
    """``sensitivity.png``: W at 2.5 ms, every ended run's deterministic endpoint by its sigma (each
    cell's sigma from its first published point's config), the grid's cell marked; drawn once a
    sensitivity cell has an ended run."""
    from nmrl.analysis import contrast_figures

    grid = grid_name("white", 0.0025)
    cells = [c for (c, _), x in groups.items() if x and (c.startswith("sensitivity/") or c == grid)]
    if not any(c.startswith("sensitivity/") for c in cells):
        return

    def sigma(cell: str) -> float | None:
        for f in sorted((dest / cell / "points").glob("*/config.json")):
            return float(json.loads(f.read_text())["sigma"])
        return None

    by = sorted((s, c) for c in cells if (s := sigma(c)) is not None)
    contrast_figures.endpoints(
        {"W at 2.5 ms": {f"σ = {s:g}" + (" (grid)" if c == grid else ""): groups[c, ""] for s, c in by}},
        dest / SENSITIVITY_FIGURE, "deterministic reward per second", "W's σ sensitivity (every ended run)")


def _panels(by_dt: dict[float, dict[str, list]]) -> dict[str, dict[str, list]]:
    """A figure's panels from ``{control step: {arm: values}}``: one per control step, coarsest
    first, titled by it, each with its arms in :data:`ARM_ORDER`."""
    return {f"control step {dt * 1000:g} ms": {a: by_dt[dt][a] for a in sorted(by_dt[dt], key=_arm_rank)}
            for dt in sorted(by_dt, reverse=True)}


def _arm_rank(arm: str) -> tuple[int, str]:
    return (ARM_ORDER.index(arm) if arm in ARM_ORDER else len(ARM_ORDER), arm)


SNR_SUMMARY_CSV, SNR_FIGURE = "snr_summary.csv", "snr.png"


def _snr_report(dest: pathlib.Path) -> None:
    """``snr_summary.csv``: per arm, iteration and control step, the SNR per second over the seeds'
    policies (cell_curves.summary: mean, 95% t interval); ``snr.png``: a panel per arm (rows) and
    policy iteration (columns), each with its own linear scale from 0 (the SNR grows by orders of
    magnitude with training): every seed's policy across the control steps (thin line, dots: the same
    networks at each step) and the mean with its t interval."""
    from nmrl.analysis import cell_curves, plots

    got = store.read_csv(dest / SNR_CSV)
    groups: dict[tuple[str, int, float], dict[int, float]] = {}
    for r in got:
        groups.setdefault((r["arm"], int(r["iteration"]), float(r["control_dt"])), {})[int(r["seed"])] = float(r["snr_per_s"])
    table = [{"arm": a, "iteration": it, "control_dt": dt, **cell_curves.summary(list(x.values()))}
             for (a, it, dt), x in sorted(groups.items())]
    store.write_csv(dest / SNR_SUMMARY_CSV, ("arm", "iteration", "control_dt", *cell_curves.SUMMARY_COLUMNS), table)
    arms = sorted({a for a, _, _ in groups}, key=_arm_rank)
    its = sorted({i for _, i, _ in groups})
    fig, axes = plots.plt.subplots(len(arms), len(its), figsize=(3.2 * len(its), 2.8 * len(arms)), squeeze=False,
                                   layout="constrained")
    for row, arm in zip(axes, arms):
        for ax, it in zip(row, its):
            dts = sorted(dt for a, i, dt in groups if (a, i) == (arm, it))
            ms = [1000 * dt for dt in dts]
            for s in sorted({s for dt in dts for s in groups[arm, it, dt]}):
                ax.plot(ms, [groups[arm, it, dt].get(s, np.nan) for dt in dts], "o-", color="0.6", lw=0.8, ms=3)
            rs = [next(r for r in table if (r["arm"], r["iteration"], r["control_dt"]) == (arm, it, dt)) for dt in dts]
            mean = [r["mean"] for r in rs]
            err = [[m - (r["ci_lo"] if r["ci_lo"] != "" else m) for m, r in zip(mean, rs)],
                   [(r["ci_hi"] if r["ci_hi"] != "" else m) - m for m, r in zip(mean, rs)]]
            ax.errorbar(ms, mean, yerr=err, marker="s", capsize=3, color=ARM_COLORS.get(arm, "tab:blue"),
                        label="mean, 95% t interval")
            ax.set_xscale("log")
            ax.set_xticks(ms, [f"{m:g}" for m in ms])
            ax.minorticks_off()
            ax.set_ylim(bottom=min(0.0, *ax.get_ylim()))
            ax.set_title(f"{arm}, policy after {it} iterations", fontsize=9)
            ax.set_xlabel("control step [ms]")
            ax.grid(alpha=0.3)
        row[0].set_ylabel("gradient SNR per second")
    axes[0][0].legend(fontsize=7)
    plots.save(fig, dest / SNR_FIGURE, dpi=110, bbox_inches="tight")
