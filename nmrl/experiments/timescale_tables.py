"""The finer-delta study's tables, its gradient measurement and its figures, from its points' files.

Everything here reads the points' ``metrics.jsonl`` in the study's directory (the cells of
nmrl/experiments/timescale_cells.py), named as :meth:`TimescaleSpec.grid_points` and
:meth:`TimescaleSpec.final_points` name them, so a directory holding only those files gives the
same tables:

* :func:`grid_rows` (``grid.csv``): every grid run's score, the mean exploring reward over the second
  half of its chunks (-inf when it diverged), and the rule's choice per (delta, arm): the highest
  score among the pairs with beta^theta <= ``beta_theta_cap`` (if set); [] until every grid point
  has finished;
* :func:`final_rows` (``final.csv``): every final run's reward per second and speed over the last
  tenth of its chunks, whether it diverged or collapsed;
* :func:`gradvar` (``gradvar.csv``): tr Cov of the per-period actor gradient estimate of fixed
  policies at every delta (nmrl/experiments/gradvar.py);
* :func:`figures` (``timescale.png``, ``grid.png``: nmrl/analysis/plots.py).
"""

from __future__ import annotations

import pathlib
import sys
import time

import jax
import numpy as np

from nmrl import learners, options, tasks
from nmrl.analysis import stats
from nmrl.experiments import gradvar as gradvar_stats
from nmrl.experiments.kit import StudyError
from nmrl.experiments.timescale import TimescaleSpec, arm_name
from nmrl.paper.control_step import DELTA_0
from nmrl.runs import checkpoint, store
from nmrl.runs.store import read_csv, read_metrics, write_csv

#: the study's learner: the paper's actor-critic (its arms are period lengths l, its grid the step sizes)
LEARNER = learners.get("ac")
GRID, FINAL = "grid", "final"
GRID_CSV, FINAL_CSV, GRADVAR_CSV = "grid.csv", "final.csv", "gradvar.csv"

GRID_COLUMNS = ("dt", "arm", "period_s", "l", "delta", "beta_theta", "beta_v", "steps", "seconds",
                "trials", "score", "avg_reward", "diverged", "chosen")
FINAL_COLUMNS = ("dt", "arm", "period_s", "l", "delta", "seed", "beta_theta", "beta_v", "steps", "seconds",
                 "trials", "avg_reward", "reward_per_s", "forward_speed", "diverged", "theta_norm_first",
                 "theta_norm", "collapsed")
#: a final run "collapsed" when its actor's parameter norm ended above this multiple of the norm after
#: its first chunk (the failure seen in this study: the actor grows, the joints are driven into their
#: limits and the penalty (10) dominates the reward; no stable run grew by more than a few percent)
COLLAPSE_FACTOR = 1.5
GRADVAR_COLUMNS = ("policy", "dt", "arm", "period_s", "l", "periods", "trcov", "trcov_ci", "mean_sq",
                   "mean_sq_ci", "snr_per_s")


def cell_name(phase: str, dt: float) -> str:
    """The directory of the cell of ``phase`` (grid or final) at control step ``dt``."""
    return f"{phase}/dt{dt:g}"


def _point(out: pathlib.Path, phase: str, dt: float, name: str) -> pathlib.Path:
    return out / cell_name(phase, dt) / "points" / name


def grid_rows(out: pathlib.Path, spec: TimescaleSpec) -> list[dict]:
    rows = []
    for dt in spec.dts:
        names, cfgs = spec.grid_points(dt)
        per_arm: dict[str, list[dict]] = {}
        for i, (n, c) in enumerate(zip(names, cfgs)):
            period = spec.periods[i // (len(spec.beta_theta_grid) * len(spec.beta_v_grid))]
            m = read_metrics(_point(out, GRID, dt, n))
            if not m or m[-1]["step"] < c.budget.steps and not any(store.is_diverged(r) for r in m):
                return []  # the grid of this delta is not finished
            diverged = any(store.is_diverged(r) for r in m)
            half = m[len(m) // 2:]
            score = float("-inf") if diverged else float(np.mean([r["avg_reward"] for r in half]))
            row = {"dt": dt, "arm": arm_name(period), "period_s": "" if period is None else period, "l": c.l,
                   "delta": c.delta, "beta_theta": c.beta_theta, "beta_v": c.beta_v, "steps": m[-1]["step"],
                   "seconds": m[-1]["step"] * dt, "trials": m[-1]["trials"], "score": score,
                   "avg_reward": stats.final_avg(m, "avg_reward"), "diverged": diverged, "chosen": False}
            per_arm.setdefault(row["arm"], []).append(row)
            rows.append(row)
        for arm_rows in per_arm.values():
            cap = spec.beta_theta_cap
            eligible = [r for r in arm_rows if cap is None or r["beta_theta"] <= cap * (1 + 1e-9)]
            best = max(eligible, key=lambda r: r["score"])
            if best["score"] == float("-inf"):
                raise StudyError(f"dt={dt:g}, arm {best['arm']}: every grid run diverged; extend the grid to smaller steps")
            best["chosen"] = True
    return rows


def chosen_betas(grid_rows: list[dict], dt: float) -> dict[str, tuple[float, float]]:
    return {r["arm"]: (float(r["beta_theta"]), float(r["beta_v"])) for r in grid_rows
            if float(r["dt"]) == dt and r["chosen"]}


def final_rows(out: pathlib.Path, spec: TimescaleSpec, grid_rows: list[dict]) -> list[dict]:
    rows = []
    for dt in spec.dts:
        names, cfgs = spec.final_points(dt, chosen_betas(grid_rows, dt))
        for i, (n, c) in enumerate(zip(names, cfgs)):
            period = spec.periods[i // spec.seeds]
            m = read_metrics(_point(out, FINAL, dt, n))
            if not m:
                continue
            avg = stats.final_avg(m, "avg_reward")
            rows.append({"dt": dt, "arm": arm_name(period), "period_s": "" if period is None else period,
                         "l": c.l, "delta": c.delta, "seed": c.budget.seed, "beta_theta": c.beta_theta,
                         "beta_v": c.beta_v, "steps": m[-1]["step"], "seconds": m[-1]["step"] * dt,
                         "trials": m[-1]["trials"], "avg_reward": avg,
                         "reward_per_s": avg / (DELTA_0 if c.environment.env == tasks.PAPER else dt),
                         "forward_speed": stats.final_avg(m, "forward_speed"),
                         "diverged": any(store.is_diverged(r) for r in m),
                         "theta_norm_first": m[0]["theta_norm"], "theta_norm": m[-1]["theta_norm"],
                         "collapsed": m[-1]["theta_norm"] > COLLAPSE_FACTOR * m[0]["theta_norm"]})
    return rows


def fixed_policies(out: pathlib.Path, spec: TimescaleSpec) -> list[tuple[str, object, object]]:
    """The fixed policies whose gradient variance is measured at every delta: the initial one (seed 0)
    and the final policies of the stationary arm and of the 0.2 s arm (or the first period arm)
    learned at the paper's control step (the largest delta of the study), each from its seed with the
    highest final average reward (a collapsed seed would say little about a working policy); the
    names say which seed, e.g. ``trained_p0.2s_s1``."""
    dt0 = max(spec.dts)
    cfg0 = spec.arm_config(dt0, None)
    tr = LEARNER.make(options.replace(cfg0, num_envs=1, steps=1))
    init = tr.init(jax.random.PRNGKey(0))
    pols = [("initial", init.theta, init.v)]
    period_arms = [p for p in spec.periods if p is not None]
    pick = 0.2 if 0.2 in period_arms else (period_arms[0] if period_arms else None)
    for p in [None] + ([pick] if pick is not None else []):
        if p not in spec.periods:
            continue
        scores = {s: stats.final_avg(read_metrics(_point(out, FINAL, dt0, f"{arm_name(p)}_s{s}")),
                                     "avg_reward") for s in range(spec.seeds)}
        best = max(scores, key=lambda s: scores[s])
        d = _point(out, FINAL, dt0, f"{arm_name(p)}_s{best}")
        cfg = checkpoint.load_config(d)
        ts = checkpoint.restore(d, learners.of(cfg).make(cfg))
        pols.append((f"trained_{arm_name(p)}_s{best}", ts.theta, ts.v))
    return pols


def gradvar(out: pathlib.Path, spec: TimescaleSpec, progress: bool) -> list[dict]:
    path = out / GRADVAR_CSV
    if path.exists():
        return read_csv(path)
    pols = fixed_policies(out, spec)
    rows = []
    for dt in spec.dts:
        t0 = time.time()
        cfgs, policies, labels = [], [], []
        for name, theta, v in pols:
            for p in spec.periods:
                c = options.replace(spec.arm_config(dt, p), num_envs=spec.gradvar_envs)
                cfgs.append(c)
                policies.append((theta, v))
                labels.append((name, p, c))
        sums = gradvar_stats.measure(cfgs, policies, batches=spec.gradvar_batches)
        for (name, p, c), s in zip(labels, sums):
            period_s = dt if p is None else p
            st = gradvar_stats.summarize(np.array(s["n"]), np.stack(s["g_sum"]), np.array(s["g_sqnorm"]), period_s)
            rows.append({"policy": name, "dt": dt, "arm": arm_name(p), "period_s": period_s, "l": c.l,
                         "periods": st["periods"], "trcov": st["trcov"], "trcov_ci": st["trcov_ci"],
                         "mean_sq": st["mean_sq"], "mean_sq_ci": st["mean_sq_ci"], "snr_per_s": st["snr_per_s"]})
        if progress:
            print(f"[gradvar dt={dt:g}] {len(cfgs)} (policy, arm) pairs in {time.time() - t0:,.0f} s",
                  file=sys.stderr, flush=True)
    write_csv(path, GRADVAR_COLUMNS, rows)
    return read_csv(path)


def tables(out: pathlib.Path, spec: TimescaleSpec) -> None:
    """``grid.csv`` once every grid point has finished, and ``final.csv`` once a final point has metrics."""
    grid = grid_rows(out, spec)
    if not grid:
        return
    write_csv(out / GRID_CSV, GRID_COLUMNS, grid)
    final = final_rows(out, spec, read_csv(out / GRID_CSV))
    if final:
        write_csv(out / FINAL_CSV, FINAL_COLUMNS, final)


def measure(out: pathlib.Path, spec: TimescaleSpec, progress: bool) -> None:
    """``gradvar.csv`` (:func:`gradvar`); StudyError unless every final run has reached its budget or diverged."""
    final = read_csv(out / FINAL_CSV) if (out / FINAL_CSV).exists() else []
    if len(final) < len(spec.dts) * len(spec.periods) * spec.seeds or any(
            float(r["seconds"]) + 1e-9 < spec.final_seconds and not r["diverged"] for r in final):
        raise StudyError(f"{out}: the final runs are not finished; run the final phase first")
    gradvar(out, spec, progress)


def figures(out: pathlib.Path) -> None:
    """``timescale.png`` and ``grid.png`` from the tables and the final points' learning curves."""
    from nmrl.analysis import plots

    if not (out / GRID_CSV).exists():
        return
    final = read_csv(out / FINAL_CSV) if (out / FINAL_CSV).exists() else []
    gv = read_csv(out / GRADVAR_CSV) if (out / GRADVAR_CSV).exists() else []
    curves: dict = {}
    for r in final:
        m = read_metrics(_point(out, FINAL, float(r["dt"]), f"{r['arm']}_s{r['seed']}"))
        curves.setdefault((r["arm"], float(r["dt"])), []).append(m)
    plots.timescale(out, read_csv(out / GRID_CSV), final, gv, curves)
