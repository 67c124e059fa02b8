"""Beyond the paper: does learning survive a finer time discretization?

The paper's thesis (Sec. III, eq. (1)): as the control step delta shrinks, a stationary policy
(white exploration noise, l = 1) learns worse, and nm-periods of a fixed *duration* do not. Its
experiment uses delta = 0.02 s only. This study runs delta in {0.02, 0.01, 0.005} s on the same
physics (5 ms MuJoCo steps, 4/2/1 per control step) and the same problem in continuous time
(nmrl/experiments/timescale.py: gamma, alpha, lambda, stop probability, Delta and rewards converted per second).

Arms, per delta: the stationary policy (l = 1) and nm-periods of 0.1, 0.2 and 0.4 s
(l = period / delta, e.g. 10, 20, 40 for 0.2 s).

The rule for step sizes (the same for every arm): a grid beta^theta x beta^v (one seed, a shorter
budget in simulated seconds) is run for every (delta, arm); the chosen pair is the one with the
highest average reward over the second half of its grid run (diverged runs are never chosen), among
the pairs with beta^theta <= ``beta_theta_cap`` if that is set. A study with a cap can reuse another
study's grid/ (copy it: finished points are never rerun) and the final runs of arms whose choice
does not change.
Every arm then runs ``seeds`` seeds at its chosen pair for the same budget in simulated seconds.

Layout of ``OUT``::

    study.json                   the spec (refuses to continue a different one)
    grid/dt{delta}/points/...    one vmapped program per delta (nmrl.runs.driver.run_points)
    grid.csv                     every grid run: delta, arm, betas, score, diverged, chosen
    final/dt{delta}/points/...   the chosen step sizes x seeds
    final.csv                    delta, arm, seed, betas, reward per second, speed, diverged
    gradvar.csv                  tr Cov of the per-period actor gradient estimate (nmrl/experiments/gradvar.py)
    timescale.png, grid.png      the figures (nmrl/analysis/plots.py)

Every phase resumes where it stopped: run the same command again. A larger ``--final-seconds``
(everything else the same) extends the final runs from their last checkpoints.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time
from typing import Sequence

import jax
import numpy as np

from nmrl.analysis import stats
from nmrl.experiments import gradvar
from nmrl.experiments.kit import StudyError
from nmrl.experiments.timescale import TimescaleSpec, arm_name
from nmrl import learners
from nmrl.paper.control_step import DELTA_0
from nmrl.paper.env import PHYSICS_HELP
from nmrl.runs import checkpoint, command, driver, lock, parser, store
from nmrl.runs.store import read_csv, read_metrics, write_csv

#: the study's learner: the paper's actor-critic (its arms are period lengths l, its grid the step sizes)
LEARNER = learners.get("ac")
TrainConfig = LEARNER.config
SPEC_FILE = "study.json"
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


def _dt_dir(out: pathlib.Path, phase: str, dt: float) -> pathlib.Path:
    return out / phase / f"dt{dt:g}"


def _point_done(d: pathlib.Path, steps: int) -> bool:
    m = read_metrics(d)
    return bool(m) and (m[-1]["step"] >= steps or any(store.is_diverged(r) for r in m))


def _run_phase(out: pathlib.Path, phase: str, dt: float, names: list[str], cfgs: list[TrainConfig],
               spec: TimescaleSpec, progress: bool) -> None:
    d = _dt_dir(out, phase, dt)
    steps = cfgs[0].steps
    phase_names = list(names)  # every point of this phase: the finished ones are the phase's, too
    todo = [i for i, n in enumerate(names) if not _point_done(d / "points" / n, steps)]
    if not todo:
        return
    names, cfgs = [names[i] for i in todo], [cfgs[i] for i in todo]  # finished points stay as they are
    dirs = [d / "points" / n for n in names]
    have = [driver.existing_step(p) is not None for p in dirs]
    if any(have) and not all(have):
        raise StudyError(f"{d}: some points have checkpoints and some do not; remove {d} to rerun this phase")
    resume = all(have)
    t0 = time.time()

    def on_chunk():
        if not progress:
            return
        rows = [read_metrics(p) for p in dirs]
        done = [r[-1] for r in rows if r]
        if not done:
            return
        step = max(r["step"] for r in done)
        avg = np.array([r["avg_reward"] for r in done])
        print(f"[{phase} dt={dt:g}] {step * dt:6.1f}/{steps * dt:g} s simulated, {len(done)} points, "
              f"avg reward median {np.median(avg):+.3f} max {avg.max():+.3f}, {time.time() - t0:,.0f} s wall",
              file=sys.stderr, flush=True)

    if progress:
        print(f"[{phase} dt={dt:g}] {'resuming' if resume else 'starting'} {len(names)} points "
              f"x {cfgs[0].num_envs} environments", file=sys.stderr, flush=True)
    driver.run_points(d, names, cfgs, resume=resume, progress=progress, table=False, known=phase_names,
                     checkpoint_every=spec.checkpoint_every, on_chunk=on_chunk)


def _grid_rows(out: pathlib.Path, spec: TimescaleSpec) -> list[dict]:
    rows = []
    for dt in spec.dts:
        names, cfgs = spec.grid_points(dt)
        per_arm: dict[str, list[dict]] = {}
        for i, (n, c) in enumerate(zip(names, cfgs)):
            period = spec.periods[i // (len(spec.beta_theta_grid) * len(spec.beta_v_grid))]
            m = read_metrics(_dt_dir(out, "grid", dt) / "points" / n)
            if not m or m[-1]["step"] < c.steps and not any(store.is_diverged(r) for r in m):
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


def _final_rows(out: pathlib.Path, spec: TimescaleSpec, grid_rows: list[dict]) -> list[dict]:
    rows = []
    for dt in spec.dts:
        names, cfgs = spec.final_points(dt, chosen_betas(grid_rows, dt))
        for i, (n, c) in enumerate(zip(names, cfgs)):
            period = spec.periods[i // spec.seeds]
            m = read_metrics(_dt_dir(out, "final", dt) / "points" / n)
            if not m:
                continue
            avg = stats.final_avg(m, "avg_reward")
            rows.append({"dt": dt, "arm": arm_name(period), "period_s": "" if period is None else period,
                         "l": c.l, "delta": c.delta, "seed": c.seed, "beta_theta": c.beta_theta,
                         "beta_v": c.beta_v, "steps": m[-1]["step"], "seconds": m[-1]["step"] * dt,
                         "trials": m[-1]["trials"], "avg_reward": avg,
                         "reward_per_s": avg / (DELTA_0 if c.env == "paper-cheetah" else dt),
                         "forward_speed": stats.final_avg(m, "forward_speed"),
                         "diverged": any(store.is_diverged(r) for r in m),
                         "theta_norm_first": m[0]["theta_norm"], "theta_norm": m[-1]["theta_norm"],
                         "collapsed": m[-1]["theta_norm"] > COLLAPSE_FACTOR * m[0]["theta_norm"]})
    return rows


def _policies(out: pathlib.Path, spec: TimescaleSpec) -> list[tuple[str, object, object]]:
    """The fixed policies whose gradient variance is measured at every delta: the initial one (seed 0)
    and the final policies of the stationary arm and of the 0.2 s arm (or the first period arm)
    learned at the paper's control step (the largest delta of the study), each from its seed with the
    highest final average reward (a collapsed seed would say little about a working policy); the
    names say which seed, e.g. ``trained_p0.2s_s1``."""
    dt0 = max(spec.dts)
    cfg0 = spec.arm_config(dt0, None)
    tr = LEARNER.make(dataclasses.replace(cfg0, num_envs=1, steps=1))
    init = tr.init(jax.random.PRNGKey(0))
    pols = [("initial", init.theta, init.v)]
    period_arms = [p for p in spec.periods if p is not None]
    pick = 0.2 if 0.2 in period_arms else (period_arms[0] if period_arms else None)
    for p in [None] + ([pick] if pick is not None else []):
        if p not in spec.periods:
            continue
        scores = {s: stats.final_avg(read_metrics(_dt_dir(out, "final", dt0) / "points" / f"{arm_name(p)}_s{s}"),
                                     "avg_reward") for s in range(spec.seeds)}
        best = max(scores, key=lambda s: scores[s])
        d = _dt_dir(out, "final", dt0) / "points" / f"{arm_name(p)}_s{best}"
        cfg = checkpoint.load_config(d)
        ts = checkpoint.restore(d, learners.of(cfg).make(cfg))
        pols.append((f"trained_{arm_name(p)}_s{best}", ts.theta, ts.v))
    return pols


def _gradvar(out: pathlib.Path, spec: TimescaleSpec, progress: bool) -> list[dict]:
    path = out / "gradvar.csv"
    if path.exists():
        return read_csv(path)
    pols = _policies(out, spec)
    rows = []
    for dt in spec.dts:
        t0 = time.time()
        cfgs, policies, labels = [], [], []
        for name, theta, v in pols:
            for p in spec.periods:
                c = dataclasses.replace(spec.arm_config(dt, p), num_envs=spec.gradvar_envs)
                cfgs.append(c)
                policies.append((theta, v))
                labels.append((name, p, c))
        sums = gradvar.measure(cfgs, policies, batches=spec.gradvar_batches)
        for (name, p, c), s in zip(labels, sums):
            period_s = dt if p is None else p
            st = gradvar.summarize(np.array(s["n"]), np.stack(s["g_sum"]), np.array(s["g_sqnorm"]), period_s)
            rows.append({"policy": name, "dt": dt, "arm": arm_name(p), "period_s": period_s, "l": c.l,
                         "periods": st["periods"], "trcov": st["trcov"], "trcov_ci": st["trcov_ci"],
                         "mean_sq": st["mean_sq"], "mean_sq_ci": st["mean_sq_ci"], "snr_per_s": st["snr_per_s"]})
        if progress:
            print(f"[gradvar dt={dt:g}] {len(cfgs)} (policy, arm) pairs in {time.time() - t0:,.0f} s",
                  file=sys.stderr, flush=True)
    write_csv(path, GRADVAR_COLUMNS, rows)
    return read_csv(path)


PHASES = ("grid", "final", "gradvar", "plot")


def run_study(spec: TimescaleSpec, out: str | pathlib.Path, *, phases: Sequence[str] = PHASES,
              progress: bool = True) -> dict:
    """Run (or continue) the study into ``out``; returns {"grid": rows, "final": rows, "gradvar": rows}."""
    spec.validate()
    out = command.study_dir(out, phases, PHASES, StudyError)
    held = lock.hold(out)  # one writer of the study for its whole run (nmrl/runs/lock.py)
    try:
        return _run_study(spec, out, phases, progress)
    finally:
        held.release(remove_if_empty=True)


def _run_study(spec: TimescaleSpec, out: pathlib.Path, phases: Sequence[str], progress: bool) -> dict:
    spec_path = out / SPEC_FILE
    if spec_path.exists():
        saved = TimescaleSpec.from_json(json.loads(spec_path.read_text()))
        diff = [f.name for f in dataclasses.fields(spec) if getattr(saved, f.name) != getattr(spec, f.name)]
        gv_fields = {"gradvar_envs", "gradvar_batches"}
        longer = "final_seconds" in diff and spec.final_seconds > saved.final_seconds
        if diff and set(diff) <= gv_fields | ({"final_seconds"} if longer else set()):
            old = out / "gradvar.csv"
            if set(diff) & gv_fields and old.exists() and not longer:
                raise StudyError(f"{old} is already measured with gradvar_envs={saved.gradvar_envs}, "
                                 f"gradvar_batches={saved.gradvar_batches}; move it away to measure again")
            if old.exists():
                # a longer final budget continues the final runs; the gradient variance of the (now
                # different) trained policies is measured again, the old table is kept beside it
                old.rename(out / f"gradvar_final{saved.final_seconds:g}s.csv")
            store.atomic_write_json(spec_path, spec.to_json())
        elif diff:
            raise StudyError(f"{out} holds a study with other settings ({', '.join(diff)}); continue it "
                             f"with the same options (a longer --final-seconds, or other --gradvar-* before "
                             f"gradvar.csv exists, may be given) or choose another --out")
    else:
        out.mkdir(parents=True, exist_ok=True)
        store.atomic_write_json(spec_path, spec.to_json())
    result: dict = {"grid": [], "final": [], "gradvar": []}
    if "grid" in phases:
        for dt in spec.dts:
            names, cfgs = spec.grid_points(dt)
            _run_phase(out, "grid", dt, names, cfgs, spec, progress)
    grid_rows = _grid_rows(out, spec)
    if grid_rows:
        write_csv(out / "grid.csv", GRID_COLUMNS, grid_rows)
        result["grid"] = read_csv(out / "grid.csv")
    if "final" in phases:
        if not grid_rows:
            raise StudyError(f"{out}: the step-size grid is not finished; run the grid phase first")
        for dt in spec.dts:
            names, cfgs = spec.final_points(dt, chosen_betas(result["grid"], dt))
            _run_phase(out, "final", dt, names, cfgs, spec, progress)
    if grid_rows:
        final_rows = _final_rows(out, spec, result["grid"])
        if final_rows:
            write_csv(out / "final.csv", FINAL_COLUMNS, final_rows)
            result["final"] = read_csv(out / "final.csv")
    if "gradvar" in phases:
        if len(result["final"]) < len(spec.dts) * len(spec.periods) * spec.seeds or any(
                float(r["seconds"]) + 1e-9 < spec.final_seconds and not r["diverged"] for r in result["final"]):
            raise StudyError(f"{out}: the final runs are not finished; run the final phase first")
        result["gradvar"] = _gradvar(out, spec, progress)
    elif (out / "gradvar.csv").exists():
        result["gradvar"] = read_csv(out / "gradvar.csv")
    if "plot" in phases and result["grid"]:
        from nmrl.analysis import plots

        curves: dict = {}
        for r in result["final"]:
            m = read_metrics(_dt_dir(out, "final", float(r["dt"])) / "points" / f"{r['arm']}_s{r['seed']}")
            curves.setdefault((r["arm"], float(r["dt"])), []).append(m)
        plots.timescale(out, result["grid"], result["final"], result["gradvar"], curves)
    return result


def _period(s: str) -> float | None:
    if s in ("stationary", "none", "1"):
        return None
    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"period {s!r} is invalid: give seconds > 0 or 'stationary'") from None
    return v


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser.OneLineParser(prog="nmrl study", description=__doc__.split("\n\n")[0])
    d = TimescaleSpec()
    ap.add_argument("--out", required=True, help="study directory (continued if it exists)")
    ap.add_argument("--dt", type=float, nargs="+", default=list(d.dts), help="control steps [s]")
    ap.add_argument("--periods", type=_period, nargs="+", default=list(d.periods),
                    help="nm-period durations [s]; 'stationary' = l = 1")
    ap.add_argument("--beta-theta", type=float, nargs="+", default=list(d.beta_theta_grid))
    ap.add_argument("--beta-v", type=float, nargs="+", default=list(d.beta_v_grid))
    ap.add_argument("--grid-seconds", type=float, default=d.grid_seconds)
    ap.add_argument("--final-seconds", type=float, default=d.final_seconds)
    ap.add_argument("--chunk-seconds", type=float, default=d.chunk_seconds)
    ap.add_argument("--seeds", type=int, default=d.seeds)
    ap.add_argument("--num-envs", type=int, default=d.num_envs)
    ap.add_argument("--checkpoint-every", type=int, default=d.checkpoint_every)
    ap.add_argument("--gradvar-envs", type=int, default=d.gradvar_envs)
    ap.add_argument("--gradvar-batches", type=int, default=d.gradvar_batches)
    ap.add_argument("--beta-theta-cap", type=float, default=None,
                    help="choose only among grid pairs with beta_theta <= this (every arm)")
    ap.add_argument("--physics", default=d.physics, help=PHYSICS_HELP)
    ap.add_argument("--env", default=d.base.env, help=LEARNER.help["env"])
    ap.add_argument("--phases", nargs="+", default=list(PHASES), help=f"any of {list(PHASES)}")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    spec = TimescaleSpec(physics=a.physics, dts=tuple(a.dt), periods=tuple(a.periods), beta_theta_grid=tuple(a.beta_theta),
                     beta_v_grid=tuple(a.beta_v), grid_seconds=a.grid_seconds, final_seconds=a.final_seconds,
                     chunk_seconds=a.chunk_seconds, seeds=a.seeds, num_envs=a.num_envs,
                     checkpoint_every=a.checkpoint_every, gradvar_envs=a.gradvar_envs,
                     gradvar_batches=a.gradvar_batches, beta_theta_cap=a.beta_theta_cap,
                     base=dataclasses.replace(d.base, env=a.env))
    return command.run("nmrl study", lambda: run_study(spec, a.out, phases=a.phases, progress=not a.quiet),
                       (StudyError,))


if __name__ == "__main__":
    sys.exit(main())
