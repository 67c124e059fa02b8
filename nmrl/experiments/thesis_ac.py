"""The third study (docs/thesis-actor-critic.md) on the kit: the paper's actor-critic at 20, 5 and
2.5 ms, the stationary policy against nm-periods of 0.1 and 0.2 s (cells:
nmrl/experiments/thesis_ac_cells.py); its registered family, report and command.

    python -m nmrl.experiments.thesis_ac run --out runs/thesis_ac [--published results/thesis_ac]
    python -m nmrl.experiments.thesis_ac publish --out runs/thesis_ac --dest results/thesis_ac
    python -m nmrl.experiments.thesis_ac progress --out runs/thesis_ac

The family: the contrasts T1-T7 of the page, each on both co-primary endpoints (the area under the
learning curve, ``auc_reward_per_s``, and the deterministic endpoint, ``det_reward_per_s``), 14
Welch tests with Holm over all of them, and TOST at +-25 (AUC) and +-50 (deterministic) reward per
second with Holm over the same 14; the secondary family the same at 5 ms, Holm apart; the step-size
check reported with Welch intervals, deciding nothing.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

from nmrl.experiments import kit, kit_cli, kit_gaits
from nmrl.experiments.thesis_ac_cells import CELLS, CHECK_DT, CHECK_FACTORS, ENDPOINT
from nmrl.paper.control_step import DELTA_0
from nmrl.runs import store

#: the co-primary endpoints (rows.csv's columns) and each one's TOST margin [reward/s]
ENDPOINTS = {"auc_reward_per_s": 25.0, "det_reward_per_s": 50.0}
ARMS = ("stationary", "p0.1s", "p0.2s")


def _c(arm: str, dt: float) -> str:
    return f"{arm}@{dt:g}"


def contrasts(fine: float) -> tuple[tuple[str, dict[str, float]], ...]:
    """T1-T7 of the page with ``fine`` (2.5 ms; 5 ms for the secondary family) against 20 ms."""
    s, coarse = "stationary", 0.02
    out = [("T1", {_c(s, fine): 1.0, _c(s, coarse): -1.0})]
    out += [(f"T{2 + i}", {_c(a, fine): 1.0, _c(s, fine): -1.0}) for i, a in enumerate(ARMS[1:])]
    out += [(f"T{4 + i}", {_c(a, fine): 1.0, _c(s, fine): -1.0, _c(a, coarse): -1.0, _c(s, coarse): 1.0})
            for i, a in enumerate(ARMS[1:])]
    out += [(f"T{6 + i}", {_c(a, fine): 1.0, _c(a, coarse): -1.0}) for i, a in enumerate(ARMS[1:])]
    return tuple(out)


def arm_of(point: str) -> str:
    """A point's arm from its name (``p0.1s_s3`` -> ``p0.1s``; ``stationary_x3_s0`` -> ``stationary_x3``)."""
    return point.rsplit("_s", 1)[0]


def cells(rows: list[dict], key: str) -> dict[str, list[float]]:
    """Each complete grid or check cell's values of ``key`` by ``arm@dt`` (a cell counts once every
    point of it has ended: at its budget, or diverged and scored by its last good policy)."""
    by: dict[str, list[float]] = {}
    complete: dict[str, bool] = {}
    for r in rows:
        if not r["cell"].startswith(("grid/", "check/")):
            continue
        k = _c(arm_of(r["point"]), float(r["control_dt"]))
        complete[r["cell"]] = complete.get(r["cell"], True) and kit.ended(r)
        if kit.ended(r) and r.get(key, "") != "":
            by.setdefault(k, []).append(float(r[key]))
    done = {_c(arm_of(r["point"]), float(r["control_dt"])) for r in rows if complete.get(r["cell"])}
    return {k: v for k, v in by.items() if k in done}


def family(rows: list[dict], fine: float) -> list[dict]:
    """T1-T7 at ``fine`` on both co-primary endpoints, decided together (module docstring): the rows
    of each endpoint with its margin and its stratified bootstrap interval beside Welch's, then Holm
    over all of them (``prereg_stats.decide``); every decision "pending" while a contrast lacks a
    complete cell."""
    from nmrl.analysis import cell_curves, prereg_stats

    out = [{"endpoint": key, **r, "margin": margin}
           for key, margin in ENDPOINTS.items()
           for r in prereg_stats.contrast_rows(cells(rows, key), contrasts(fine), margin, cell_curves.BOOTSTRAP_REPS)]
    return prereg_stats.decide(out)


def verdict(fam: list[dict]) -> str:
    """The page's reading of the decided primary family: "holds" when on one co-primary endpoint T1
    has the stationary policy behind and T4 or T5 has the nm-periods ahead, and T6 and T7 show a loss
    on neither endpoint; "fails" when on both endpoints T1 does not have the stationary policy behind
    and neither T4 nor T5 has the nm-periods ahead; else "mixed" (reported contrast by contrast);
    "pending" while the family is."""
    if any(r["decision"] == "pending" for r in fam):
        return "pending"
    d = {(r["endpoint"], r["contrast"]): r["decision"] for r in fam}
    loss = any(d[e, t] == "behind" for e in ENDPOINTS for t in ("T6", "T7"))
    lead = {e: d[e, "T1"] == "behind" and "ahead" in (d[e, "T4"], d[e, "T5"]) for e in ENDPOINTS}
    none = all(d[e, "T1"] != "behind" and "ahead" not in (d[e, "T4"], d[e, "T5"]) for e in ENDPOINTS)
    return "holds" if any(lead.values()) and not loss else "fails" if none else "mixed"


def check(rows: list[dict]) -> list[dict]:
    """The comparator's step-size check: each scaled stationary cell at 2.5 ms minus the grid's, on
    both endpoints, with its Welch interval (deciding nothing)."""
    from nmrl.analysis import prereg_stats

    out = []
    for key in ENDPOINTS:
        by = cells(rows, key)
        base = by.get(_c("stationary", CHECK_DT))
        for f in CHECK_FACTORS:
            k = _c(f"stationary_x{f:.3g}", CHECK_DT)
            row = {"endpoint": key, "contrast": f"step sizes x{f:.3g}", "cells": f"+1*{k} -1*{_c('stationary', CHECK_DT)}"}
            if base is None or len(by.get(k, ())) < 2:
                out.append({**row, "decision": "pending"})
                continue
            r = prereg_stats.welch(np.asarray(by[k]), np.asarray(base))
            out.append({**row, "n": f"{len(by[k])} {len(base)}", "estimate": r.diff, "lo": r.lo, "hi": r.hi,
                        "p": r.p, "decision": "reported"})
    return out


#: the row of ``analysis.csv`` that carries :func:`step_size_reading`
STEP_SIZE_ROW = "T1-T5 on the paper's step size"


def step_size_reading(checked: list[dict]) -> str:
    """The page's reading of the step-size check: "conditional" (T1-T5 are stated as conditional on
    the paper's step size) when a scaled cell's estimate lies above the endpoint's margin on either
    endpoint, the cautious reading of "beats by more than the margin" (4 runs against 8 detect
    little); "unconditional" when none does; "pending" while a check cell is."""
    if any(r["decision"] == "pending" for r in checked):
        return "pending"
    return "conditional" if any(float(r["estimate"]) > ENDPOINTS[r["endpoint"]] for r in checked) else "unconditional"


def analysis(rows: list[dict]) -> list[dict]:
    """The primary family (2.5 ms) and its :func:`verdict`, the secondary (5 ms), the check and its
    :func:`step_size_reading`, as ``analysis.csv``'s rows."""
    primary, checked = family(rows, 0.0025), check(rows)
    return ([{"family": "primary", **r} for r in primary]
            + [{"family": "primary", "contrast": "the thesis", "decision": verdict(primary)}]
            + [{"family": "secondary", **r} for r in family(rows, 0.005)]
            + [{"family": "check", **r} for r in checked]
            + [{"family": "check", "contrast": STEP_SIZE_ROW, "decision": step_size_reading(checked)}])


#: the control step whose gaits are drawn, and the arms it draws: the stationary policy and the
#: nm-period arm whose cell has the higher mean deterministic endpoint there
GAIT_DT = 0.0025


def gait_picks(rows: list[dict]) -> list[dict] | None:
    """The stationary arm's and the best nm-period arm's median run at :data:`GAIT_DT` (the lower of
    the middle two by the deterministic endpoint), each {name, arm, cell, point, seed,
    det_reward_per_s, cell_mean}; None while the cell is incomplete."""
    by = cells(rows, "det_reward_per_s")
    means = {a: float(np.mean(by[_c(a, GAIT_DT)])) for a in ARMS if _c(a, GAIT_DT) in by}
    if len(means) < len(ARMS):
        return None
    best = max(ARMS[1:], key=lambda a: means[a])
    cell = f"grid/dt{GAIT_DT:g}"
    return [kit_gaits.pick((r for r in rows if r["cell"] == cell and arm_of(r["point"]) == arm), name=name, arm=arm,
                           cell=cell, cell_mean=means[arm])
            for name, arm in (("stationary", "stationary"), (f"best_{best}", best))]


def gaits(out: pathlib.Path, rows: list[dict]) -> None:
    """The gaits of :func:`gait_picks` (nmrl/experiments/kit_gaits.py), once the 2.5 ms cell is complete."""
    picks = gait_picks(rows)
    if picks is not None:
        kit_gaits.draw(out, picks, lambda c: f"{'l = 1' if c['arm'] == 'stationary' else 'nm-periods of ' + c['arm'][1:]}"
                                             f" at 2.5 ms, seed {c['seed']}, deterministic policy")




LEARNING_FIGURE, ENDPOINT_FIGURE = "learning_curves.png", "endpoints.png"
#: the contrasts' figure of each co-primary endpoint: its file and what the endpoint is called there
CONTRAST_FIGURES = {"auc_reward_per_s": ("contrasts.png", "AUC"),
                    "det_reward_per_s": ("contrasts_deterministic.png", "deterministic endpoint")}
CELLS_CSV, SECONDARY_CSV = "cells.csv", "secondary.csv"
#: the page's secondary measures: the exploring reward per second over the last 10% of the run's
#: chunks, the deterministic forward speed [m/s], and the actor's parameter norm at the end
SECONDARY = ("last10_reward_per_s", "det_forward_speed", "theta_norm")


def point_secondary(point: pathlib.Path) -> dict[str, float]:
    """A published point's secondary measures from its metrics (a diverged run's by its last finite
    chunk): the mean exploring reward per second of its last round(n / 10) chunks and the actor's
    norm at its last chunk."""
    m = [r for r in store.read_metrics(point) if not r.get("diverged") and np.isfinite(r["theta_norm"])]
    k = max(1, round(len(m) / 10))
    return {"last10_reward_per_s": float(np.mean([r["avg_reward"] for r in m[-k:]])) / DELTA_0,
            "theta_norm": float(m[-1]["theta_norm"])}


def secondary(rows: list[dict], dest: pathlib.Path) -> list[dict]:
    """``secondary.csv``: per complete grid cell and secondary measure its runs' summary
    (``cell_curves.summary``) and how many diverged, then T1-T7 at 2.5 ms and at 5 ms on each measure
    with its Welch interval (reported, deciding nothing)."""
    from nmrl.analysis import cell_curves, prereg_stats

    measured = []
    for r in rows:
        point = dest / r["cell"] / "points" / r["point"]
        if r["cell"].startswith("grid/") and kit.ended(r) and (point / "metrics.jsonl").is_file():
            measured.append({**r, **point_secondary(point)})
    out = []
    for key in SECONDARY:
        for k, v in cells(measured, key).items():
            n_div = sum(r["diverged"] == "True" for r in measured if _c(arm_of(r["point"]), float(r["control_dt"])) == k)
            out.append({"table": "cell", "measure": key, "cell": k, **cell_curves.summary(v), "diverged": n_div})
        for fine in (0.0025, 0.005):
            for r in prereg_stats.contrast_rows(cells(measured, key), contrasts(fine), margin=1.0):
                r.pop("tost_p", None)
                out.append({"table": f"contrast at {fine * 1000:g} ms", "measure": key, **r})
    return out


def cell_summaries(rows: list[dict]) -> list[dict]:
    """Per complete cell (``arm@dt``) and co-primary endpoint: the runs, mean, SD, 95% t interval and
    the IQM with its stratified bootstrap interval (``cell_curves.summary``: the page's aggregate
    intervals, reported, deciding nothing)."""
    from nmrl.analysis import cell_curves

    return [{"cell": k, "endpoint": key, **cell_curves.summary(v)}
            for key in ENDPOINTS for k, v in cells(rows, key).items()]


def report(rows: list[dict], dest: pathlib.Path) -> None:
    """``cells.csv`` (:func:`cell_summaries`), ``secondary.csv`` (:func:`secondary`), the learning curves with seed bands (one panel per
    control step, from 20 ms to the finest, a line per arm), every ended run's deterministic endpoint with each cell's
    interval, and the decided contrasts of each co-primary endpoint against its margin
    (:data:`CONTRAST_FIGURES`), from the published points alone."""
    from nmrl.analysis import cell_curves, contrast_figures

    store.write_csv(dest / CELLS_CSV, ["cell", "endpoint", *cell_curves.SUMMARY_COLUMNS], cell_summaries(rows))
    table = secondary(rows, dest)
    store.write_csv(dest / SECONDARY_CSV, list(dict.fromkeys(k for r in table for k in r)), table)

    rows = sorted(rows, key=lambda r: -float(r["control_dt"]))  # panels from the coarse step to the fine
    curves: dict[str, dict[str, list]] = {}
    for r in rows:
        point = dest / r["cell"] / "points" / r["point"]
        if r["cell"].startswith("grid/") and (point / "metrics.jsonl").is_file():
            panel = f"control step {float(r['control_dt']) * 1000:g} ms"
            curves.setdefault(panel, {}).setdefault(arm_of(r["point"]), []).append(kit.learning_curve(point))
    if curves:
        cell_curves.figure(curves, dest / LEARNING_FIGURE, "exploring reward per second", "the grid")
    det: dict[str, dict[str, list[float]]] = {}
    for r in rows:
        if r["cell"].startswith("grid/") and kit.ended(r) and r.get("det_reward_per_s", "") != "":
            det.setdefault(f"control step {float(r['control_dt']) * 1000:g} ms", {}).setdefault(
                arm_of(r["point"]), []).append(float(r["det_reward_per_s"]))
    if det:
        contrast_figures.endpoints(det, dest / ENDPOINT_FIGURE, "deterministic reward per second",
                                   "every ended run, each cell's mean and 95% t interval")
    decided = [r for r in analysis(rows) if r.get("estimate", "") != "" and r["family"] != "check"]
    label = {"primary": "2.5 ms", "secondary": "5 ms"}  # each row named by its family's fine step
    for key, (path, what) in CONTRAST_FIGURES.items():
        table = [{**r, "family": label[r["family"]]} for r in decided if r["endpoint"] == key]
        if table:
            contrast_figures.contrasts(table, ENDPOINTS[key], dest / path,
                                       f"difference of the {what}, reward per second (95% Welch interval)",
                                       f"the registered contrasts on the {what}\n(decisions: Holm over both "
                                       "endpoints in each family, the primary at 2.5 ms, the secondary at 5 ms)")


STUDY = kit.Study(name="thesis_ac", cells=CELLS, endpoint=ENDPOINT, analysis=analysis, report=report,
                  measurements=(kit.Measurement(kit_gaits.GAITS, gaits),))


def main(argv: list[str] | None = None) -> int:
    return kit_cli.main(STUDY, argv, "python -m nmrl.experiments.thesis_ac", __doc__.split("\n\n")[0])


if __name__ == "__main__":
    sys.exit(main())
