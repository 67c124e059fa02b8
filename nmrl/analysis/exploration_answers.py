"""The first exploration x control-step study's numbers: functions of its rows, nothing trained.

The study (docs/exploration-study.md, its record in results/exploration/) ran the native PPO with
every process of nmrl.explore at three control steps. Its tables are rows: ``results.csv`` (one row
per grid run: ``avg_reward_per_s`` the exploring policy's average reward per second over the last
iteration, ``det_reward_per_s`` the deterministic policy's over a 10 s evaluation,
``auc_reward_per_s`` the exploring policy's mean over every iteration; the rewards (8)-(14) are
rates, so reward per second = mean r_t / 0.02 s at every control step), ``control.csv`` (the
samples-per-update control's runs, the same columns) and ``screen.csv`` (the screen's runs and
their scores).

* The screen's rule (:func:`choose`): per process, the setting whose seeds have the highest mean
  *score* (:func:`score`: the average reward per control step over the second half of the run's
  iterations); a diverged run is never chosen.
* The answers (:func:`answers`): per (control step, process) the mean and 95% t-interval over
  seeds; differences of two cells with Welch's interval, and differences of changes with the
  Welch-Satterthwaite interval (nmrl.analysis.stats). :func:`analysis` is the study's whole
  analysis of its rows, the numbers of ``summary.json``.
"""

from __future__ import annotations

import math
from typing import Iterable, Sequence

import numpy as np

from nmrl.analysis import stats
from nmrl.paper.control_step import DELTA_0
from nmrl.runs import store

RESULT_COLUMNS = ("learner", "exploration", "setting", "control_dt", "seed", "control_steps", "simulated_s",
                  "iterations", "avg_reward", "avg_reward_per_s", "auc_reward_per_s", "det_reward", "det_reward_per_s",
                  "forward_speed", "det_forward_speed", "diverged")
SCREEN_COLUMNS = ("exploration", "field", "value", "seed", "iterations", "score", "diverged", "chosen")


def score(rows: Sequence[dict]) -> float:
    """The screen's score of one run: mean ``avg_reward`` over the second half of its chunks
    (the later half when the count is odd); -inf for a diverged run or one without chunks."""
    if not rows or any(store.is_diverged(r) for r in rows):
        return -math.inf
    half = rows[len(rows) // 2:]
    return float(np.mean([r["avg_reward"] for r in half]))


def choose(screen_rows: Sequence[dict]) -> dict[str, tuple[str, float]]:
    """``{process: (field, value)}``: per process, the value whose runs have the highest mean
    score (ties: the first value listed); a value with a diverged run scores -inf."""
    by: dict[str, dict[float, list[float]]] = {}
    fields: dict[str, str] = {}
    for r in screen_rows:
        by.setdefault(r["exploration"], {}).setdefault(float(r["value"]), []).append(float(r["score"]))
        fields[r["exploration"]] = r["field"]
    out = {}
    for proc, vals in by.items():
        best = max(vals, key=lambda v: (np.mean(vals[v]) if all(math.isfinite(s) for s in vals[v]) else -math.inf))
        out[proc] = (fields[proc], best)
    return out


def cells(rows: Iterable[dict], key: str) -> dict[tuple[float, str], np.ndarray]:
    """``{(control_dt, exploration): values of key over seeds}`` (NaN values dropped)."""
    out: dict[tuple[float, str], list[float]] = {}
    for r in rows:
        v = float(r[key])
        if math.isfinite(v):
            out.setdefault((float(r["control_dt"]), r["exploration"]), []).append(v)
    return {k: np.array(v) for k, v in out.items()}


def cell_table(rows: Sequence[dict], key: str) -> list[dict]:
    """Per (control step, process): seeds, mean and 95% t half-width of ``key``."""
    out = []
    for (dt, proc), v in sorted(cells(rows, key).items()):
        m, h = stats.mean_ci95(v) if len(v) > 1 else (float(v.mean()), float("nan"))
        out.append({"control_dt": dt, "exploration": proc, "n": len(v), "mean": m, "ci95": h})
    return out


def diff(rows: Sequence[dict], key: str, a: tuple[float, str], b: tuple[float, str]) -> dict | None:
    """Cell ``a`` minus cell ``b`` of ``key``: difference of the means and Welch's 95% half-width
    (None if either cell has fewer than 2 values)."""
    c = cells(rows, key)
    if a not in c or b not in c or len(c[a]) < 2 or len(c[b]) < 2:
        return None
    d, h = stats.diff_ci95(c[b], c[a])  # mean(a) - mean(b)
    return {"a": list(a), "b": list(b), "diff": d, "ci95": h, "significant": bool(abs(d) > h)}


def interaction(rows: Sequence[dict], key: str, a: str, b: str, fine: float, coarse: float) -> dict | None:
    """How much more process ``a`` changes from ``coarse`` to ``fine`` than process ``b`` does:
    ``(a_fine - a_coarse) - (b_fine - b_coarse)`` of ``key`` with its Welch-Satterthwaite 95%
    half-width (nmrl.analysis.stats.contrast_ci95; None if a cell has fewer than 2 values). The
    paper's thesis in one number: with ``b`` = white, a process that keeps its exploration at fine
    control steps loses less than white, so its interaction is positive."""
    c = cells(rows, key)
    need = [(fine, a), (coarse, a), (fine, b), (coarse, b)]
    if any(k not in c or len(c[k]) < 2 for k in need):
        return None
    d, h = stats.contrast_ci95([c[k] for k in need], [1.0, -1.0, -1.0, 1.0])
    return {"a": a, "b": b, "fine": fine, "coarse": coarse, "diff": d, "ci95": h,
            "significant": bool(abs(d) > h)}


def step_pairs(dts: Sequence[float]) -> list[tuple[float, float]]:
    """``(finer, coarser)`` for each control step and the next coarser one, where there are more
    than two steps (with two, the one pair is the coarsest-to-finest change itself)."""
    d = sorted(set(dts), reverse=True)
    return [(f, c) for c, f in zip(d, d[1:])] if len(d) > 2 else []


def answers(rows: Sequence[dict], dts: Sequence[float], processes: Sequence[str],
            key: str = "avg_reward_per_s") -> dict:
    """The study's questions as numbers (docs/exploration-study.md): white's change from the
    coarsest to the finest control step; every process against white at each control step; every
    process's own change, from the coarsest to the finest step and from each step to the next finer
    one (:func:`step_pairs`), and that change against white's (:func:`interaction`); every process at
    the finest step against white at the coarsest; the best process per control step (where every
    process has runs) and its lead over the second; nm-periods against each stationary correlated
    process."""
    coarse, fine = max(dts), min(dts)
    out: dict = {"key": key, "cells": cell_table(rows, key)}
    out["white_fine_minus_coarse"] = diff(rows, key, (fine, "white"), (coarse, "white"))
    out["process_minus_white"] = [d for dt in dts for p in processes if p != "white"
                                  for d in [diff(rows, key, (dt, p), (dt, "white"))] if d]
    out["process_fine_minus_coarse"] = [d for p in processes for d in [diff(rows, key, (fine, p), (coarse, p))] if d]
    out["process_step_change"] = [d for finer, coarser in step_pairs(dts) for p in processes
                                  for d in [diff(rows, key, (finer, p), (coarser, p))] if d]
    out["process_fine_minus_white_coarse"] = [d for p in processes if p != "white"
                                              for d in [diff(rows, key, (fine, p), (coarse, "white"))] if d]
    out["change_minus_white_change"] = [d for p in processes if p != "white"
                                        for d in [interaction(rows, key, p, "white", fine, coarse)] if d]
    best, margin = {}, {}
    for dt in dts:
        have = [t for t in out["cells"] if t["control_dt"] == dt]
        if {t["exploration"] for t in have} >= set(processes):
            first, second = sorted(have, key=lambda t: -t["mean"])[:2]
            best[f"{dt:g}"] = first["exploration"]
            margin[f"{dt:g}"] = diff(rows, key, (dt, first["exploration"]), (dt, second["exploration"]))
    out["best"] = best
    out["best_margin"] = margin
    out["nm_periods_minus_stationary"] = [d for dt in dts for p in ("ou", "colored") if p in processes
                                          for d in [diff(rows, key, (dt, "nm-periods"), (dt, p))] if d]
    return out


#: the control's label in its rows' ``exploration`` column while it is compared with the grid
CONTROL = "white, more environments"
#: the measures every comparison is made for, by their results.csv column
KEYS = ("avg_reward_per_s", "det_reward_per_s", "auc_reward_per_s")


def control_answers(control: Sequence[dict], grid: Sequence[dict], coarse: float, fine: float) -> dict:
    """The samples-per-update control as numbers: `white` at the ``coarse`` control step with
    ``coarse / fine`` times the environments and the minibatch (so each Adam step sees as many
    samples as at ``fine``, in the same number of Adam steps, over that many times the simulated
    time) against `white` at ``fine`` (is the finer step's gain more than the samples per update?)
    and at ``coarse`` (do more samples per update help at the coarse step?). Per measure of
    :data:`KEYS`: the control's cell and both Welch differences (None where a side has fewer than
    2 finished runs)."""
    rows = [{**r, "exploration": CONTROL} for r in control] + [r for r in grid if r["exploration"] == "white"]
    out = {}
    for key in KEYS:
        cell = [c for c in cell_table(rows, key) if c["exploration"] == CONTROL]
        out[key] = {"cell": cell[0] if cell else None,
                    "minus_white_fine": diff(rows, key, (coarse, CONTROL), (fine, "white")),
                    "minus_white_coarse": diff(rows, key, (coarse, CONTROL), (coarse, "white"))}
    return out


def iteration_means(runs: Sequence[Sequence[dict]]) -> list[dict]:
    """Per PPO iteration (one ``metrics.jsonl`` row each) that every run of ``runs`` has reached:
    the exploring policy's average reward per second, mean and 95% t half-width over the runs."""
    n = min((len(m) for m in runs), default=0)
    out = []
    for i in range(n):
        m, h = stats.mean_ci95(np.array([r[i]["avg_reward"] for r in runs], float) / DELTA_0)
        out.append({"iteration": i + 1, "mean": m, "ci95": h, "runs": len(runs)})
    return out


def finished(rows: Sequence[dict], iterations: int) -> list[dict]:
    """The rows of runs that are over: their full ``iterations``, or diverged. The answers are made
    of these only (a run half way through is not a result)."""
    return [r for r in rows if int(r["iterations"]) >= iterations or r["diverged"] is True]


def best_and_worst(rows: Sequence[dict], dt: float, processes: Sequence[str], key: str = "avg_reward_per_s"
                   ) -> list[tuple[str, int]] | None:
    """``[(best process, its median seed), (worst process, its median seed)]`` at control step
    ``dt`` by the mean of ``key`` over seeds (the median seed: the run nearest the cell's median,
    the lower one of an even count); None unless every process has runs there."""
    c = {p: [(float(r[key]), int(r["seed"])) for r in rows if float(r["control_dt"]) == dt
             and r["exploration"] == p and math.isfinite(float(r[key]))] for p in processes}
    if any(not v for v in c.values()):
        return None
    mean = {p: np.mean([x for x, _ in v]) for p, v in c.items()}
    out = []
    for p in (max(mean, key=mean.get), min(mean, key=mean.get)):
        v = sorted(c[p])
        out.append((p, v[(len(v) - 1) // 2][1]))
    return out


def analysis(results: Sequence[dict], control: Sequence[dict], screen: Sequence[dict], dts: Sequence[float],
             processes: Sequence[str], iterations: int) -> dict:
    """The study's analysis of its rows (``summary.json``'s numbers): of the grid's finished runs,
    :func:`answers` per measure (the exploring policy's last iteration, the deterministic policy,
    the whole run); the screen's choice (:func:`choose`); and, where the control has runs, its
    answers against `white` at the finest and the coarsest control step (:func:`control_answers`)."""
    done = finished(results, iterations)
    out = {"runs": len(results), "finished_runs": len(done),
           "answers": answers(done, dts, processes),
           "answers_deterministic": answers(done, dts, processes, key="det_reward_per_s"),
           "answers_auc": answers(done, dts, processes, key="auc_reward_per_s"),
           "chosen": {k: {"field": f, "value": v} for k, (f, v) in choose(screen).items()}}
    if control:
        ctl = finished(control, iterations)
        out["control"] = {"runs": len(control), "finished_runs": len(ctl),
                          "answers": control_answers(ctl, done, max(dts), min(dts))}
    return out
