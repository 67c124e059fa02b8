"""The exploration x control-step study: its rules, its rows and answers, its SNR estimate, its command.

The numbers are checked against independent computations: NumPy means, scipy's t and Welch
intervals, a plain-NumPy GAE and the normal density of ``jax.scipy.stats`` for the gradient
estimate; the command's bad input against the house rule (one line, exit 2, nothing written).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from nmrl.analysis import exploration_results as xr
from nmrl.experiments import exploration_study as es

REPO = pathlib.Path(__file__).resolve().parents[1]


def _metrics(point: pathlib.Path, rows: list[dict]) -> None:
    point.mkdir(parents=True, exist_ok=True)
    with open(point / "metrics.jsonl", "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")


def _rows(rewards, diverged_at=None, step0=5120):
    return [{"step": step0 * (i + 1), "trials": 10 * (i + 1), "avg_reward": r, "forward_speed": r / 2,
             "diverged": diverged_at is not None and i >= diverged_at} for i, r in enumerate(rewards)]


def test_score_is_the_mean_of_the_second_half_and_diverged_scores_minus_inf():
    assert math.isclose(xr.score(_rows([-5.0, -3.0, -1.0, 2.0])), np.mean([-1.0, 2.0]))
    assert math.isclose(xr.score(_rows([-5.0, -3.0, -1.0])), np.mean([-3.0, -1.0]))  # odd: the later half
    assert xr.score(_rows([1.0, 2.0, 3.0, 4.0], diverged_at=3)) == -math.inf
    assert xr.score([]) == -math.inf


def test_choose_takes_the_best_mean_over_seeds_and_never_a_diverged_setting():
    rows = [
        {"exploration": "ou", "field": "corr_time_s", "value": 0.045, "score": 1.0},
        {"exploration": "ou", "field": "corr_time_s", "value": 0.045, "score": 3.0},  # mean 2.0
        {"exploration": "ou", "field": "corr_time_s", "value": 0.09, "score": 2.5},
        {"exploration": "ou", "field": "corr_time_s", "value": 0.09, "score": 2.0},  # mean 2.25: chosen
        {"exploration": "ou", "field": "corr_time_s", "value": 0.18, "score": 9.0},
        {"exploration": "ou", "field": "corr_time_s", "value": 0.18, "score": -math.inf},  # a diverged seed
        {"exploration": "colored", "field": "beta", "value": 0.5, "score": 1.0},
        {"exploration": "colored", "field": "beta", "value": 1.0, "score": 1.0},  # tie: the first listed
    ]
    assert xr.choose(rows) == {"ou": ("corr_time_s", 0.09), "colored": ("beta", 0.5)}


def test_run_row_converts_to_reward_per_second_and_reads_the_deterministic_evaluation(tmp_path):
    p = tmp_path / "s1"
    rewards = [float(x) for x in np.linspace(-3, 2, 16)]
    _metrics(p, _rows(rewards, step0=20480))
    (p / "eval").mkdir()
    (p / "eval" / "eval.json").write_text(json.dumps(
        {"step": 16 * 20480, "deterministic": {"avg_reward": 3.1, "forward_speed": 3.3},
         "exploring": {"avg_reward": 2.0, "forward_speed": 2.2}}))
    r = xr.run_row(p, exploration="ou", setting="corr_time_s=0.09", control_dt=0.005, seed=1, num_envs=64,
                   iteration_steps=20480)
    assert r["control_steps"] == 16 * 20480 * 64 and math.isclose(r["simulated_s"], 16 * 20480 * 64 * 0.005)
    assert r["iterations"] == 16 and r["diverged"] is False
    assert math.isclose(r["avg_reward"], rewards[-1])  # the last tenth of 16 chunks: the last one
    assert math.isclose(r["avg_reward_per_s"], rewards[-1] / 0.02)
    assert math.isclose(r["auc_reward_per_s"], np.mean(rewards) / 0.02, rel_tol=1e-12)  # the curve's mean
    assert math.isclose(r["det_reward_per_s"], 3.1 / 0.02) and r["det_forward_speed"] == 3.3
    # an evaluation of an earlier step is not this run's
    (p / "eval" / "eval.json").write_text(json.dumps({"step": 8 * 20480, "deterministic": {
        "avg_reward": 1.0, "forward_speed": 1.0}}))
    r = xr.run_row(p, exploration="ou", setting="-", control_dt=0.005, seed=1, num_envs=64, iteration_steps=20480)
    assert math.isnan(r["det_reward"])


def test_answers_match_scipy_t_and_welch_intervals():
    rng = np.random.default_rng(3)
    rows = []
    vals = {}
    for dt in (0.02, 0.005):
        for p in es.PROCESSES:
            v = rng.normal(2.0 + (p == "nm-periods") - (dt == 0.005) * (p == "white"), 0.4, size=4)
            vals[(dt, p)] = v
            rows += [{"control_dt": dt, "exploration": p, "avg_reward_per_s": x} for x in v]
    a = xr.answers(rows, (0.02, 0.005), es.PROCESSES)
    for c in a["cells"]:
        v = vals[(c["control_dt"], c["exploration"])]
        lo, hi = scipy.stats.t.interval(0.95, len(v) - 1, loc=v.mean(), scale=scipy.stats.sem(v))
        assert math.isclose(c["mean"], v.mean()) and math.isclose(c["ci95"], (hi - lo) / 2, rel_tol=1e-9)

    def welch(x, y):
        vx, vy = x.var(ddof=1) / len(x), y.var(ddof=1) / len(y)
        df = (vx + vy) ** 2 / (vx ** 2 / (len(x) - 1) + vy ** 2 / (len(y) - 1))
        return x.mean() - y.mean(), scipy.stats.t.ppf(0.975, df) * math.sqrt(vx + vy)

    d, h = welch(vals[(0.005, "white")], vals[(0.02, "white")])
    w = a["white_fine_minus_coarse"]
    assert math.isclose(w["diff"], d) and math.isclose(w["ci95"], h, rel_tol=1e-9)
    assert w["significant"] == (abs(d) > h)
    nm = {(tuple(x["a"]), tuple(x["b"])): x for x in a["nm_periods_minus_stationary"]}
    d, h = welch(vals[(0.005, "nm-periods")], vals[(0.005, "ou")])
    x = nm[((0.005, "nm-periods"), (0.005, "ou"))]
    assert math.isclose(x["diff"], d) and math.isclose(x["ci95"], h, rel_tol=1e-9)
    for dt in (0.02, 0.005):
        means = {p: vals[(dt, p)].mean() for p in es.PROCESSES}
        assert a["best"][f"{dt:g}"] == max(means, key=means.get)
    assert a["process_step_change"] == []  # two control steps: the one change is the coarse-to-fine one


def _welch(x, y):
    vx, vy = x.var(ddof=1) / len(x), y.var(ddof=1) / len(y)
    df = (vx + vy) ** 2 / (vx ** 2 / (len(x) - 1) + vy ** 2 / (len(y) - 1))
    return x.mean() - y.mean(), scipy.stats.t.ppf(0.975, df) * math.sqrt(vx + vy)


def test_each_step_to_the_next_finer_one_is_a_welch_difference_in_the_tables_and_the_words():
    """With 20, 10 and 5 ms every process also has its change 20 → 10 ms and 10 → 5 ms: Welch
    intervals as scipy gives them, a row each in the change table, and white's in answer 1."""
    rng = np.random.default_rng(5)
    level = {0.02: 1.0, 0.01: 3.0, 0.005: 3.05}  # white: a clear gain, then none
    vals, rows = {}, []
    for dt in (0.02, 0.005, 0.01):
        for p in es.PROCESSES:
            vals[(dt, p)] = v = rng.normal(level[dt], 0.3, size=4)
            rows += [{"control_dt": dt, "exploration": p, "avg_reward_per_s": x} for x in v]
    a = xr.answers(rows, (0.02, 0.005, 0.01), es.PROCESSES)
    got = {(tuple(x["a"]), tuple(x["b"])): x for x in a["process_step_change"]}
    assert len(got) == 2 * len(es.PROCESSES)
    for finer, coarser in ((0.01, 0.02), (0.005, 0.01)):
        for p in es.PROCESSES:
            d, h = _welch(vals[(finer, p)], vals[(coarser, p)])
            x = got[((finer, p), (coarser, p))]
            assert math.isclose(x["diff"], d) and math.isclose(x["ci95"], h, rel_tol=1e-9)
    md = xr.report({"answers": a, "runs": len(rows), "finished_runs": len(rows)}, [], [], [],
                   (0.02, 0.005, 0.01), es.PROCESSES, 16)
    d1, h1 = _welch(vals[(0.01, "white")], vals[(0.02, "white")])
    d2, h2 = _welch(vals[(0.005, "white")], vals[(0.01, "white")])
    assert abs(d1) > h1 and abs(d2) < h2
    assert f"| 10 ms − 20 ms | {d1:+.1f} ± {h1:.1f} **(significant)** |" in md
    assert f"| 5 ms − 10 ms | {d2:+.1f} ± {h2:.1f} |" in md
    (q1,) = [ln for ln in md.splitlines() if ln.startswith("1. ")]
    assert f"10 ms − 20 ms: {d1:+.1f} ± {h1:.1f} per s, an improvement." in q1
    assert f"5 ms − 10 ms: {d2:+.1f} ± {h2:.1f} per s, no significant difference." in q1



def test_the_control_cell_has_the_finest_steps_samples_per_adam_step_at_the_coarsest_step():
    """The samples-per-update control: `white` at 20 ms whose every Adam step sees as many samples
    as one at 5 ms (minibatch unrolls x unroll length), in as many Adam steps per iteration, with
    4x the simulated time per iteration; none with one control step or a ratio that is not whole."""
    spec = es.StudySpec()
    c = es.control_cell(spec)
    assert (c.phase, c.dt, c.process, c.envs_factor, c.seeds, c.iterations) == ("control", 0.02, "white", 4, 4, 16)
    ctl = c.sweep_spec(spec).base.resolved()
    fine = es.grid_cell(spec, 0.005, "white", {}).sweep_spec(spec).base.resolved()
    coarse = es.grid_cell(spec, 0.02, "white", {}).sweep_spec(spec).base.resolved()
    assert ctl.batch_size * round(ctl.unroll_s / ctl.control_dt) == fine.batch_size * round(fine.unroll_s / 0.005)
    assert (ctl.epochs, ctl.num_minibatches) == (fine.epochs, fine.num_minibatches)
    per_iteration_s = lambda cfg: cfg.num_envs * cfg.iteration_steps * cfg.control_dt  # noqa: E731
    assert per_iteration_s(ctl) == pytest.approx(4 * per_iteration_s(fine))
    assert dataclasses.replace(ctl, num_envs=64, batch_size=512) == coarse  # otherwise the 20 ms white cell
    assert es.control_cell(es.StudySpec(dts=(0.02, 0.01))).envs_factor == 2
    assert es.control_cell(es.StudySpec(dts=(0.02,))) is None
    assert es.control_cell(es.StudySpec(dts=(0.015, 0.01))) is None


def test_the_control_answers_are_welch_differences_and_its_curves_t_intervals():
    rng = np.random.default_rng(11)
    fine, coarse = 0.005, 0.02
    vals = {k: rng.normal(m, 0.5, size=4) for k, m in (("ctl", 1.0), ("fine", 3.0), ("coarse", 1.2))}
    row = lambda dt, p, v: {"control_dt": dt, "exploration": p, "avg_reward_per_s": v,  # noqa: E731
                            "det_reward_per_s": 2 * v, "auc_reward_per_s": v / 2}
    control = [row(coarse, "white", v) for v in vals["ctl"]]
    grid = [row(fine, "white", v) for v in vals["fine"]] + [row(coarse, "white", v) for v in vals["coarse"]] + \
        [row(fine, "ou", 99.0), row(fine, "ou", 98.0)]
    a = xr.control_answers(control, grid, coarse, fine)
    for key, scale in (("avg_reward_per_s", 1), ("det_reward_per_s", 2), ("auc_reward_per_s", 0.5)):
        for name, other in (("minus_white_fine", "fine"), ("minus_white_coarse", "coarse")):
            d, h = _welch(scale * vals["ctl"], scale * vals[other])
            x = a[key][name]
            assert math.isclose(x["diff"], d) and math.isclose(x["ci95"], h, rel_tol=1e-9)
            assert x["significant"] == (abs(d) > h)
        lo, hi = scipy.stats.t.interval(0.95, 3, loc=scale * vals["ctl"].mean(), scale=scipy.stats.sem(scale * vals["ctl"]))
        assert math.isclose(a[key]["cell"]["ci95"], (hi - lo) / 2, rel_tol=1e-9) and a[key]["cell"]["n"] == 4
    assert xr.control_answers(control[:1], grid, coarse, fine)["avg_reward_per_s"]["minus_white_fine"] is None

    runs = [[{"avg_reward": float(x)} for x in rng.normal(size=n)] for n in (5, 4, 6)]  # 4 iterations in common
    means = xr.iteration_means(runs)
    assert [m["iteration"] for m in means] == [1, 2, 3, 4]
    for i, m in enumerate(means):
        v = np.array([r[i]["avg_reward"] for r in runs]) / 0.02
        lo, hi = scipy.stats.t.interval(0.95, 2, loc=v.mean(), scale=scipy.stats.sem(v))
        assert math.isclose(m["mean"], v.mean()) and math.isclose(m["ci95"], (hi - lo) / 2, rel_tol=1e-9)


def test_the_control_figure_draws_each_curve_against_iterations_and_simulated_seconds(tmp_path, saved_figures):
    """control.png: the control's and both `white` cells' mean curves with their 95% bands, against
    the PPO iteration and against one run's simulated seconds (iteration x seconds per iteration)."""
    curve = lambda m: [{"iteration": i + 1, "mean": m + i, "ci95": 0.5, "runs": 4} for i in range(3)]  # noqa: E731
    ctl = {"envs_factor": 4, "coarse": 0.02, "fine": 0.005,
           "iterations": {"control": curve(1.0), "white_fine": curve(2.0), "white_coarse": curve(0.0)},
           "seconds_per_iteration": {"control": 4 * 6553.6, "white_fine": 6553.6, "white_coarse": 6553.6}}
    path = xr.draw_control(ctl, tmp_path / "control.png")
    assert path.is_file()
    ((saved, fig),) = saved_figures
    assert saved == path
    by_iteration, by_time = fig.axes
    for ax, scale in ((by_iteration, {"control": 1, "white_fine": 1, "white_coarse": 1}),
                      (by_time, ctl["seconds_per_iteration"])):
        lines = {ln.get_label().split(" (")[0]: ln for ln in ax.get_lines()}
        assert len(lines) == 3 and len(ax.collections) == 3  # a band per curve
        for label, key, m in (("white 20 ms, 4× environments", "control", 1.0), ("white 5 ms", "white_fine", 2.0),
                              ("white 20 ms", "white_coarse", 0.0)):
            x, y = lines[label].get_data()
            np.testing.assert_allclose(x, np.arange(1, 4) * scale[key])
            np.testing.assert_allclose(y, m + np.arange(3))


@pytest.mark.parametrize("ctl_mean,ctl_auc_shift,verdict", [
    (1.0, 0.0, "The finer step helps beyond the samples per update."),
    (3.0, 0.0, "The finer step's gain may be the samples per update."),
    (3.0, -2.0, "at the last iteration the two are not distinguishable."),
    (9.0, 0.0, "the samples per update explain its gain.")])
def test_the_control_in_words_and_tables_follows_its_interval(ctl_mean, ctl_auc_shift, verdict):
    """Question 6's verdict from the control's intervals against `white` at the finest step: the
    last iteration's first, the whole run's where the last iteration does not decide."""
    rng = np.random.default_rng(2)
    fine, coarse = 0.005, 0.02
    row = lambda dt, v, shift=0.0: {"control_dt": dt, "exploration": "white", "avg_reward_per_s": v,  # noqa: E731
                                    "det_reward_per_s": v, "auc_reward_per_s": v + shift}
    ctl_v = rng.normal(ctl_mean, 0.3, size=4)
    fine_v = rng.normal(3.0, 0.3, size=4)
    grid = [row(fine, v) for v in fine_v] + [row(coarse, v) for v in rng.normal(1.0, 0.3, size=4)]
    a = xr.control_answers([row(coarse, v, ctl_auc_shift) for v in ctl_v], grid, coarse, fine)
    curve = [{"iteration": 1, "mean": 1.5, "ci95": 0.25, "runs": 4}]
    summary = {"control": {"envs_factor": 4, "coarse": coarse, "fine": fine, "num_envs": 256, "batch_size": 2048,
                           "runs": 4, "finished_runs": 4, "command": "nmrl sweep --num-envs 256", "answers": a,
                           "iterations": {"control": curve, "white_fine": curve, "white_coarse": []}}}
    md = xr.report(summary, [], [], [], (0.02, 0.005), es.PROCESSES, 16)
    (q6,) = [ln for ln in md.splitlines() if ln.startswith("6. ")]
    d, h = _welch(ctl_v, fine_v)
    assert f"− `white` at 5 ms {d:+.1f} ± {h:.1f} per s" in q6 and q6.endswith(verdict)
    assert "## The samples-per-update control" in md and "`nmrl sweep --num-envs 256`" in md
    assert f"| exploring, last iteration | {ctl_v.mean():+.1f}" in md
    assert "| 1 | +1.5 ± 0.2 | +1.5 ± 0.2 | – |" in md
    assert "6. " not in xr.report({}, [], [], [], (0.02, 0.005), es.PROCESSES, 16)


def test_the_answers_are_made_of_finished_runs_only(tmp_path):
    """summary.json's cells hold the seeds with the full budget (or diverged); a seed half way
    through is in results.csv at its iteration but not in the answers."""
    spec = es.StudySpec(dts=(0.02,), seeds=4)
    cell = es.grid_cell(spec, 0.02, "white", {})
    finals = {0: 1.5, 1: 0.5, 2: 9.0, 3: -20.0}
    for s, last in finals.items():
        n = 16 if s < 2 else 8  # seed 2 is half way; seed 3 diverged at its 5th iteration
        rewards = [0.0] * (n - 1) + [last]
        _metrics(cell.dir(tmp_path) / "points" / f"s{s}",
                 _rows(rewards if s != 3 else [0.0] * 4 + [last], diverged_at=4 if s == 3 else None))
    rows = es.write_results(tmp_path, spec, None)
    assert sorted(int(r["iterations"]) for r in rows) == [5, 8, 16, 16]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert (summary["runs"], summary["finished_runs"]) == (4, 3)
    assert summary["commands"] == {"0.02/white": cell.command(spec, out="runs/rerun/dt0.02/white")}
    md = xr.report(summary, rows, [], [], spec.dts, es.PROCESSES, 16)
    assert f"* white at 20 ms: `{cell.command(spec, out='runs/rerun/dt0.02/white')}`" in md
    (c,) = summary["answers"]["cells"]
    v = np.array([finals[0], finals[1], finals[3]]) / 0.02
    lo, hi = scipy.stats.t.interval(0.95, 2, loc=v.mean(), scale=scipy.stats.sem(v))
    assert c["n"] == 3 and math.isclose(c["mean"], v.mean()) and math.isclose(c["ci95"], (hi - lo) / 2)


def test_the_screen_rule_on_the_grids_first_iterations_gives_white_its_screen_score(tmp_path):
    """At the screen's control step the grid's seeds 0..screen_seeds-1 are scored over their first
    screen_iterations chunks (the second half: chunks 3-4), like the screen's runs."""
    spec = es.StudySpec(dts=(0.005,), seeds=3)
    chosen = {"nm-periods": ("period_s", 0.1), "ou": ("corr_time_s", 0.045), "colored": ("beta", 0.5)}
    rng = np.random.default_rng(2)
    want = {}
    for proc in ("white", "ou"):
        cell = es.grid_cell(spec, 0.005, proc, chosen)
        for s in range(3):
            r = rng.normal(-5, 1, size=16 if s != 1 or proc == "white" else 3)  # ou seed 1: 3 chunks only
            _metrics(cell.dir(tmp_path) / "points" / f"s{s}", _rows(list(map(float, r)), step0=20480))
            if s < 2 and len(r) >= 4:
                want[(proc, s)] = float(np.mean(r[2:4]))
    es.write_results(tmp_path, spec, chosen)
    got = json.loads((tmp_path / "summary.json").read_text())["screen_from_grid"]
    assert {(g["exploration"], g["seed"]) for g in got} == set(want)
    for g in got:
        assert math.isclose(g["score"], want[(g["exploration"], g["seed"])], rel_tol=1e-6)
    assert next(g for g in got if g["exploration"] == "ou")["setting"] == "corr_time_s=0.045"


def test_the_report_shows_each_cell_and_difference_of_the_finished_runs():
    rng = np.random.default_rng(5)
    rows, vals = [], {}
    for dt in (0.02, 0.005):
        for p in es.PROCESSES:
            v = rng.normal(50 + 10 * (p == "ou"), 5, size=4)
            its = [16, 16, 16, 16] if (dt, p) != (0.005, "colored") else [16, 9, 9, 9]
            vals[(dt, p)] = v[[i for i, n in enumerate(its) if n == 16]]
            rows += [{"control_dt": dt, "exploration": p, "iterations": n, "diverged": False, "avg_reward_per_s": x,
                      "det_reward_per_s": x + 1} for x, n in zip(v, its)]
    done = xr.finished(rows, 16)
    assert len(done) == len(rows) - 3
    summary = {"answers": xr.answers(done, (0.02, 0.005), es.PROCESSES),
               "answers_deterministic": xr.answers(done, (0.02, 0.005), es.PROCESSES, key="det_reward_per_s")}
    # no answers_auc: its table is drawn with empty cells
    snr = [{"control_dt": 0.005, "exploration": "ou", "setting": "corr_time_s=0.045", "policy": "initial",
            "step": 0, "trcov": 2.0, "trcov_ci": 0.5, "mean_sq": 0.04, "mean_sq_ci": 0.01, "snr_per_s": 1.953e-4}]
    md = xr.report(summary, rows, [], snr, (0.02, 0.005), es.PROCESSES, 16)
    assert f"**{len(done)} of {len(rows)} grid runs**" in md
    auc = md[md.index("## Exploring policy: average reward per second over the whole run"):md.index("## The gradient")]
    assert "(n=" not in auc and "| white | – | – |" in auc
    v = vals[(0.005, "white")]
    h = scipy.stats.t.ppf(0.975, 3) * v.std(ddof=1) / 2
    assert f"| white | {vals[(0.02, 'white')].mean():+.1f}" in md and f"{v.mean():+.1f} ± {h:.1f} (n=4) |" in md
    assert "(n=1)" in md and f"{vals[(0.005, 'colored')][0]:+.1f} (n=1)" in md  # the one finished colored seed
    x, y = vals[(0.005, "ou")], vals[(0.005, "white")]
    vx, vy = x.var(ddof=1) / 4, y.var(ddof=1) / 4
    df = (vx + vy) ** 2 / (vx ** 2 / 3 + vy ** 2 / 3)
    d, hw = x.mean() - y.mean(), scipy.stats.t.ppf(0.975, df) * math.sqrt(vx + vy)
    line = next(ln for ln in md.splitlines() if ln.startswith("| ou − white |"))
    assert f"{d:+.1f} ± {hw:.1f}" + (" **(significant)**" if abs(d) > hw else "") in line.split("|")[3]
    assert "| 5 ms | ou | corr_time_s=0.045 | initial (0) | 2 ± 0.5 | 0.04 ± 0.01 | 0.000195 |" in md


def _welch_satterthwaite(samples, weights):
    """sum w_i mean_i and its 95% half-width, written out with numpy and scipy's t quantile."""
    v = [w * w * np.var(x, ddof=1) / len(x) for w, x in zip(weights, samples)]
    df = sum(v) ** 2 / sum(vi ** 2 / (len(x) - 1) for vi, x in zip(v, samples))
    return sum(w * np.mean(x) for w, x in zip(weights, samples)), scipy.stats.t.ppf(0.975, df) * math.sqrt(sum(v))


def _grid_rows(level, rng, dts=(0.02, 0.005), seeds=4, spread=1.0):
    """Finished rows whose exploring, deterministic and whole-run rewards per second are level(dt, p)
    plus normal noise."""
    rows, vals = [], {}
    for dt in dts:
        for p in es.PROCESSES:
            v = level(dt, p) + rng.normal(0, spread, seeds)
            vals[(dt, p)] = v
            rows += [{"control_dt": dt, "exploration": p, "iterations": 16, "diverged": False, "avg_reward_per_s": x,
                      "det_reward_per_s": x + 0.5, "auc_reward_per_s": x / 2} for x in v]
    return rows, vals


def _summary(rows, dts=(0.02, 0.005)):
    return {k: xr.answers(rows, dts, es.PROCESSES, key=key) for k, key in
            (("answers", "avg_reward_per_s"), ("answers_deterministic", "det_reward_per_s"),
             ("answers_auc", "auc_reward_per_s"))}


def _line(lines, start):
    return next(ln for ln in lines if ln.lstrip().startswith(start))


@pytest.mark.parametrize("white_lead", [0.0, 3.0])
def test_the_answers_in_words_follow_the_intervals_when_white_degrades_and_nm_periods_does_not(white_lead):
    """white, ou and colored lose 100 per s from 20 to 5 ms; nm-periods keeps its level; seeds
    spread by 1 per s; white is ``white_lead`` per s above the others at both steps. The words must
    say: white degrades (with scipy's Welch interval); nm-periods loses less than white (the
    interaction, written out with Welch-Satterthwaite here), which removes the degradation when
    nm-periods at 5 ms reaches white at 20 ms and only reduces it when white leads by 3; nm-periods
    is best at 5 ms by a significant lead and ahead of both stationary processes; colored's lead
    over white does not grow."""
    rng = np.random.default_rng(11)
    rows, v = _grid_rows(lambda dt, p: 100.0 - 100.0 * (dt == 0.005) * (p != "nm-periods") + white_lead * (p == "white"),
                         rng)
    lines = xr.plain_answers(_summary(rows), (0.02, 0.005), es.PROCESSES)
    q1 = _line(lines, "1.")
    d, h = _welch_satterthwaite([v[(0.02, "white")], v[(0.005, "white")]], [-1, 1])
    lo, hi = scipy.stats.ttest_ind(v[(0.005, "white")], v[(0.02, "white")], equal_var=False).confidence_interval(0.95)
    assert math.isclose(d - h, lo) and math.isclose(d + h, hi)
    assert f"{d:+.1f} ± {h:.1f} per s" in q1 and q1.endswith("yes, it degrades.")
    nm = _line(lines, "* `nm-periods`:")
    i, hi_ = _welch_satterthwaite([v[(0.005, "nm-periods")], v[(0.02, "nm-periods")], v[(0.005, "white")],
                                   v[(0.02, "white")]], [1, -1, -1, 1])
    assert f"against `white`'s {i:+.1f} ± {hi_:.1f} per s" in nm and "loses significantly less than `white`" in nm
    assert "loses significantly" not in _line(lines, "* `ou`:")  # ou changes as white does
    verdict = _line(lines, "* Removed by" if white_lead == 0 else "* Reduced but not removed by")
    assert "`nm-periods`" in verdict and "`ou`" not in verdict and "`colored`" not in verdict
    assert _line(lines, "* 5 ms: `nm-periods`").endswith("a significant lead.")
    if white_lead:
        assert _line(lines, "* 20 ms: `white`").endswith("a significant lead.")
    reset = _line(lines, "* 5 ms: nm-periods −")
    assert reset.count("significantly ahead") == 2
    cn = _line(lines, "* CN-PPO")
    assert "5 ms" in cn and "20 ms" in cn and cn.endswith("no significant difference.")


def test_the_answers_in_words_say_what_is_not_yet_measured_and_when_there_is_nothing_to_remove():
    rng = np.random.default_rng(12)
    rows, _ = _grid_rows(lambda dt, p: 10.0, rng, dts=(0.02,))
    lines = xr.plain_answers(_summary(rows, (0.02,)), (0.02, 0.005), es.PROCESSES)
    assert _line(lines, "1.").endswith("5 ms − 20 ms: not yet measured (`white` needs finished runs at both).")
    assert "Not yet answerable" in "\n".join(lines)
    assert _line(lines, "* 5 ms:").endswith("not yet measured (every process needs finished runs).")
    assert "not yet measured, not yet measured" not in "\n".join(lines)
    assert _line(lines, "* 5 ms: nm-periods −").strip() == "* 5 ms: nm-periods − `ou` not yet measured; − `colored` not yet measured."
    rows, _ = _grid_rows(lambda dt, p: 10.0 + 50.0 * (dt == 0.005), rng)  # everything improves at 5 ms
    lines = xr.plain_answers(_summary(rows), (0.02, 0.005), es.PROCESSES)
    assert _line(lines, "1.").endswith("no, it improves.")
    assert "* `white` improves significantly, so there is no degradation to remove" in "\n".join(lines)
    assert "Removed by" not in "\n".join(lines)


def test_the_summary_figure_draws_the_finished_seeds_means_intervals_and_snr(tmp_path, saved_figures):
    from matplotlib.container import ErrorbarContainer

    rng = np.random.default_rng(8)
    rows = []
    for dt in (0.02, 0.005):
        for p in es.PROCESSES:
            for s, n in enumerate((16, 16, 16, 7)):  # seed 3 is not over: not drawn
                rows.append({"control_dt": dt, "exploration": p, "seed": s, "iterations": n, "diverged": False,
                             "avg_reward_per_s": float(rng.normal(40, 9)), "det_reward_per_s": float(rng.normal(60, 9))})
    snr = [{"control_dt": dt, "exploration": "white", "policy": pol, "snr_per_s": v, "trcov": 10 * v,
            "trcov_ci": v} for dt, pol, v in ((0.02, "mid", 3e-3), (0.005, "mid", 1e-3), (0.02, "initial", 2e-3))]
    xr.draw_summary(rows, snr, (0.02, 0.005), es.PROCESSES, 16, tmp_path / "summary.png")
    ((path, fig),) = saved_figures
    assert path.name == "summary.png"
    for ax, key in zip(fig.axes[:2], ("avg_reward_per_s", "det_reward_per_s")):
        bars = {c.get_label(): c for c in ax.containers if isinstance(c, ErrorbarContainer)}
        assert len(bars) == 4
        x, y = (np.asarray(a, float) for a in bars["ou (mean, 95% CI)"].lines[0].get_data())
        np.testing.assert_allclose(x, [0.02, 0.005])
        for k, dt in enumerate((0.02, 0.005)):
            v = np.array([r[key] for r in rows if r["exploration"] == "ou" and r["control_dt"] == dt
                          and r["iterations"] == 16])
            lo, hi = scipy.stats.t.interval(0.95, 2, loc=v.mean(), scale=scipy.stats.sem(v))
            assert math.isclose(y[k], v.mean())
            seg = bars["ou (mean, 95% CI)"].lines[2][0].get_segments()[k]
            assert math.isclose(seg[1][1] - seg[0][1], hi - lo, rel_tol=1e-9)
    lines = {c.get_label(): c.lines[0] for c in fig.axes[2].containers if isinstance(c, ErrorbarContainer)}
    assert set(lines) == {"white, mid", "white, initial"}
    np.testing.assert_allclose(np.asarray(lines["white, mid"].get_ydata(), float), [3e-3, 1e-3])
    np.testing.assert_allclose(np.asarray(lines["white, initial"].get_ydata(), float), [2e-3])


def test_gaits_are_drawn_one_above_the_other_at_one_scale(tmp_path, saved_figures):
    """Two gaits of different control steps and reach: each panel shows its own poses every 0.1 s of
    the first 3 s under its title, and both panels span the same metres with the same metres per
    pixel, so the runner's 6 m and the stander's 0.2 m compare by eye."""
    rng = np.random.default_rng(0)
    base = rng.uniform(0.0, 0.8, size=(10, 2))
    files = []
    for name, dt, speed in (("runner", 0.005, 2.0), ("stander", 0.02, 0.05)):
        t = np.arange(round(10.0 / dt) + 1) * dt
        pos = base[None] + np.stack([speed * t, np.zeros_like(t)], axis=-1)[:, None, :]
        np.savez(tmp_path / f"{name}.npz", pos=pos.astype(np.float32), control_dt=dt)
        files.append((f"{name} at {dt * 1000:g} ms", tmp_path / f"{name}.npz", pos, dt))
    xr.draw_gaits([(title, f) for title, f, _, _ in files], tmp_path / "both.png")
    ((path, fig),) = saved_figures
    assert path == tmp_path / "both.png" and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    axes = fig.axes
    assert [ax.get_title().split("\n")[0] for ax in axes] == ["runner at 5 ms", "stander at 20 ms"]
    for ax, (_, _, pos, dt) in zip(axes, files):
        sticks = [ln for ln in ax.lines if len(ln.get_xdata()) == 10]
        shown = [round(k * 0.1 / dt) for k in range(31)]  # 0, 0.1, ..., 3.0 s
        assert len(sticks) == len(shown)
        for ln, i in zip(sticks, shown):
            np.testing.assert_allclose(np.column_stack(ln.get_data()), pos[i], atol=1e-6)
    assert axes[0].get_xlim() == axes[1].get_xlim() and axes[0].get_ylim() == axes[1].get_ylim()
    lo, hi = axes[0].get_xlim()
    assert lo <= base[:, 0].min() and hi >= base[:, 0].max() + 2.0 * 3.0  # the runner's 6 m fit
    fig.canvas.draw()
    per_m = [ax.transData.transform([(1.0, 1.0)]) - ax.transData.transform([(0.0, 0.0)]) for ax in axes]
    np.testing.assert_allclose(per_m[0], per_m[1], rtol=1e-6)
    assert per_m[0][0, 0] == pytest.approx(per_m[0][0, 1], rel=1e-6)  # equal metres in x and y


def test_a_grid_cells_command_parses_back_to_its_config_through_nmrl_sweeps_parser():
    """Each grid cell's re-run command, read by the real ``nmrl sweep`` parser, gives the cell's
    config (the one its points run), its seed count and checkpointing."""
    import shlex

    from nmrl import cli

    spec = es.StudySpec()
    chosen = {"nm-periods": ("period_s", 0.1), "ou": ("corr_time_s", 0.045), "colored": ("beta", 0.5)}
    learner = cli._learner("ppo")
    for c in [*es.grid_cells(spec, chosen), es.control_cell(spec)]:
        argv = shlex.split(c.command(spec, out="/tmp/x"))
        assert argv[:2] == ["nmrl", "sweep"]
        args = cli.build_parser(learner).parse_args(argv[1:])
        got = cli.config_from_args(args, skip=cli._sweep_skip(learner))
        want = c.sweep_spec(spec).base
        assert dataclasses.replace(got, seed=want.seed) == want, c
        assert (args.seeds, args.checkpoint_every, args.out) == (4, 1, "/tmp/x")
    with pytest.raises(ValueError, match="varies"):
        es.screen_cells(spec)[0].command(spec)


def test_study_configs_are_in_seconds():
    spec = es.StudySpec()
    spec.validate()
    for dt, T, k in ((0.02, 20, 1.0), (0.01, 40, 0.5), (0.005, 80, 0.25)):
        c = spec.config(dt, "white").resolved()
        assert c.unroll_length == T and math.isclose(c.reward_scale, k)
        assert c.iteration_steps * dt == pytest.approx(102.4)  # seconds of experience per environment
        assert (c.value_layers, c.value_width, c.num_envs) == (2, 64, 64)
    # nm-periods at 20 ms with the paper's alpha = 0.8 per step and l = 10 for 0.2 s
    c = spec.config(0.02, "nm-periods", period_s=0.2)
    assert math.isclose(math.exp(-0.02 / c.corr_time_s), 0.8, abs_tol=1e-4)
    assert round(c.period_s / 0.02) == 10
    assert es.physics_timestep() == 0.005


def test_screen_and_grid_cells():
    spec = es.StudySpec()
    cells = es.screen_cells(spec)
    assert {c.process for c in cells} == {"nm-periods", "ou", "colored"}
    assert all(c.dt == 0.005 and len(c.points()) == 3 * spec.screen_seeds for c in cells)
    grid = es.grid_cells(spec, {"nm-periods": ("period_s", 0.1), "ou": ("corr_time_s", 0.09),
                                "colored": ("beta", 1.0)})
    assert [(c.dt, c.process) for c in grid[:4]] == [(0.02, p) for p in es.PROCESSES]
    assert len(grid) == 12 and all(c.points() == [f"s{s}" for s in range(4)] for c in grid)
    nm = [c for c in grid if c.process == "nm-periods"][0]
    assert dict(nm.setting) == {"period_s": 0.1, "corr_time_s": es.NM_CORR_TIME_S}
    base = nm.sweep_spec(spec).base
    assert base.steps == 16 * 5120 and base.period_s == 0.1
    assert es.grid_cells(spec, None) == [c for c in grid if c.process == "white"]


def _cli(*args, cwd, timeout=120):
    return subprocess.run([sys.executable, "-m", "nmrl.cli", "explore-study", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("args,needle", [
    (("--seeds", "0"), "seeds=0"),
    (("--dt", "0.007"), "0.007"),
    (("--dt", "0.02", "0.02"), "appear once"),
    (("--dt", "-0.02"), "> 0 s"),
    (("--phases", "train"), "train"),
    (("--iterations", "1"), "iterations=1"),
    (("--snr-batches", "1"), "snr_batches=1"),
    (("--published", "no/such/dir"), "no/such/dir"),
])
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, args, needle):
    out = tmp_path / "study"
    assert es.main(["--out", str(out), *args]) == 2
    lines = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(lines) == 1 and needle in lines[0] and lines[0].startswith("nmrl explore-study: error:"), lines
    assert not out.exists()


def test_the_command_refuses_bad_input_through_nmrl(tmp_path):
    out = tmp_path / "study"
    r = _cli("--out", str(out), "--screen-dt", "0.0125", cwd=REPO)
    assert r.returncode == 2 and "0.0125" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not out.exists()


def test_a_study_refuses_other_settings(tmp_path):
    out = tmp_path / "study"
    out.mkdir()
    (out / es.SPEC_FILE).write_text(json.dumps(es.StudySpec(seeds=3).to_json()))
    with pytest.raises(es.StudyError, match="seeds"):
        es._check_spec(out, es.StudySpec(seeds=4))
    es._check_spec(out, es.StudySpec(seeds=3, iterations=20))  # a longer budget continues it
    assert json.loads((out / es.SPEC_FILE).read_text())["iterations"] == 20
    with pytest.raises(es.StudyError, match="iterations"):
        es._check_spec(out, es.StudySpec(seeds=3, iterations=16))


# ------------------------------------------------------------------------------------- the SNR
def test_gradient_estimate_per_environment_matches_an_independent_computation():
    """make_batch's sums of g_e = grad (1/UT) sum A log pi, for white noise, against GAE in NumPy
    (by its definition) and the normal density of jax.scipy.stats on the policy's mean and std."""
    from tests.test_ppo import TINY, _np_gae
    from tests.tiny_env import TinyEnv
    from jax.flatten_util import ravel_pytree
    from nmrl.experiments import ppo_gradsnr
    from nmrl.learners import ppo
    from nmrl.learners import ppo_networks as nn_

    cfg = ppo.PPOConfig(**dict(TINY, num_envs=3, batch_size=6), exploration="white", reward_scale=0.5).resolved()
    env = TinyEnv(stop_prob=0.1)
    tr = ppo.make_ppo(cfg, env)
    st = tr.init(jax.random.PRNGKey(1))
    st = st.replace(obs_stats=st.obs_stats._replace(mean=st.obs_stats.mean + 0.1))
    key = jax.random.PRNGKey(7)
    new, (n, g_sum, g_sq) = jax.jit(ppo_gradsnr.make_batch(cfg, env))(st, key)
    (_, _, _), data = jax.jit(tr.rollout)(st, key)  # the same rollout (same state, same key)
    h = st.hyper
    N, U, T = data.reward.shape
    obs_n = nn_.normalize(st.obs_stats, data.obs)
    v = np.asarray(nn_.value(tr.nets, st.value, obs_n), np.float64)
    boot = np.asarray(nn_.value(tr.nets, st.value, nn_.normalize(st.obs_stats, data.next_obs)), np.float64)
    adv = np.zeros((N, U, T))
    for e in range(N):
        _, a = _np_gae(np.asarray(data.reward[e], np.float64).T * float(h.reward_scale), v[e].T, boot[e],
                       np.asarray(data.termination[e]).T > 0, np.asarray(data.truncation[e]).T > 0,
                       float(h.gamma), float(h.lam))
        adv[e] = a.T
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    grads = []
    for e in range(N):
        def obj(p):
            mu, std = nn_.mean_std(tr.nets, p, obs_n[e], cfg.min_std)
            lp = jnp.sum(jax.scipy.stats.norm.logpdf(data.x[e], mu, std), axis=-1)
            return jnp.sum(jnp.asarray(adv[e], jnp.float32) * lp) / (U * T)
        grads.append(np.asarray(ravel_pytree(jax.grad(obj)(st.policy))[0], np.float64))
    grads = np.stack(grads)
    assert float(n) == N
    np.testing.assert_allclose(np.asarray(g_sum), grads.sum(0), rtol=2e-4, atol=1e-6)
    np.testing.assert_allclose(float(g_sq), np.sum(grads ** 2), rtol=2e-4)
    assert int(new.step) == int(st.step)  # no learning: the counters and parameters stay
    np.testing.assert_array_equal(ravel_pytree(new.policy)[0], ravel_pytree(st.policy)[0])


_SIDE_BY_SIDE = """
import json, jax, numpy as np
from nmrl.experiments import gradvar, ppo_gradsnr
from nmrl.learners import ppo
from tests.test_ppo import TINY
from tests.tiny_env import TinyEnv
assert jax.local_device_count() == 2, jax.devices()
cfg = ppo.PPOConfig(**dict(TINY, num_envs=3, batch_size=6), exploration="ou", reward_scale=0.5).resolved()
env = TinyEnv(stop_prob=0.1)
tr = ppo.make_ppo(cfg, env)
states = [tr.init(jax.random.PRNGKey(s)) for s in (1, 2, 3)]
many = ppo_gradsnr.measure_many(cfg, states, batches=2, seed=5, warmup=1, env=env)
batch = jax.jit(ppo_gradsnr.make_batch(cfg, env))
plain = []
for st in states:  # one policy at a time: the warm-up rollout, then two counted ones
    key, sums = jax.random.PRNGKey(5), []
    for b in range(3):
        key, k = jax.random.split(key)
        st, s = batch(st, k)
        if b:
            sums.append(jax.device_get(s))
    n, g, q = (np.array([np.asarray(x[i], np.float64) for x in sums]) for i in range(3))
    plain.append(gradvar.summarize(n, g, q, cfg.unrolls_per_env * cfg.unroll_s))
print(json.dumps([many, plain]))
"""


def test_policies_measured_side_by_side_on_two_devices_match_one_at_a_time(tmp_path):
    """measure_many over 2 devices (3 policies: one device holds two, one slot idle) gives each
    policy what a plain loop of the batch function (checked above against NumPy) gives it alone."""
    import os

    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu",
           "PYTHONPATH": str(REPO)}
    p = subprocess.run([sys.executable, "-c", _SIDE_BY_SIDE], env=env, cwd=REPO, capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    many, plain = json.loads(p.stdout.strip().splitlines()[-1])
    assert len(many) == len(plain) == 3
    assert len({round(m["trcov"], 9) for m in many}) == 3  # three different policies
    for m, q in zip(many, plain):
        assert (m["periods"], m["batches"]) == (q["periods"], q["batches"]) == (6, 2)
        for k in ("trcov", "trcov_ci", "mean_sq", "mean_sq_ci", "snr_per_s"):
            np.testing.assert_allclose(m[k], q[k], rtol=1e-3, atol=1e-9, err_msg=k)


def test_a_signal_during_the_snr_phase_stops_it_after_the_measurement_in_flight(tmp_path, monkeypatch, capsys):
    """A SIGTERM that arrives while one process's SNR is measured stops the phase as soon as that
    measurement is written (not after the whole control step); running again measures the rest."""
    import signal
    import types

    from nmrl.experiments import ppo_gradsnr
    from nmrl.runs import checkpoint, signals

    measured = []

    def measure_many(cfg, states, batches, seed):
        measured.append(cfg.exploration)
        if len(measured) == 1:
            os.kill(os.getpid(), signal.SIGTERM)  # arrives while the first process is measured
        return [{"periods": 6, "batches": batches, "seconds_per_estimate": 1.0, "trcov": 2.0, "trcov_ci": 0.1,
                 "mean_sq": 1.0, "mean_sq_ci": 0.1, "snr_per_s": 0.5} for _ in states]

    monkeypatch.setattr(checkpoint, "has_compact", lambda d: True)
    monkeypatch.setattr(checkpoint, "restore_compact", lambda d, learner: types.SimpleNamespace(step=80))
    monkeypatch.setattr(ppo_gradsnr, "initial_state", lambda cfg, seed: types.SimpleNamespace(step=0))
    monkeypatch.setattr(ppo_gradsnr, "measure_many", measure_many)
    spec = es.StudySpec(dts=(0.02,))
    chosen = {"nm-periods": ("period_s", 0.1), "ou": ("corr_time_s", 0.09), "colored": ("beta", 1.0)}
    with signals.Guard(write=lambda line: None):
        with pytest.raises(signals.Interrupted) as e:
            es._snr(tmp_path, spec, chosen, progress=False)
    assert e.value.exit_status == 128 + signal.SIGTERM
    assert measured == ["white"]
    rows = list(csv_rows(tmp_path / "snr.csv"))
    assert [(r["exploration"], r["policy"]) for r in rows] == [("white", "initial"), ("white", "mid")]
    assert "after the SNR of white at 0.02 s was written" in capsys.readouterr().err
    with signals.Guard(write=lambda line: None):
        es._snr(tmp_path, spec, chosen, progress=False)
    assert measured == list(es.PROCESSES)
    assert len(list(csv_rows(tmp_path / "snr.csv"))) == 2 * len(es.PROCESSES)


@pytest.mark.slow
def test_a_tiny_study_runs_every_phase_and_continues(tmp_path):
    """Every phase on a tiny budget through the command: the white cell, the screen and its choice,
    the grid with mid-training states, evaluations, results, the SNR table; a second call has
    nothing left to do."""
    out = tmp_path / "study"
    args = ["--out", str(out), "--dt", "0.02", "0.01", "--screen-dt", "0.01", "--seeds", "2", "--iterations", "2",
            "--screen-seeds", "1", "--screen-iterations", "1", "--num-envs", "4", "--batch-size", "4",
            "--num-minibatches", "1", "--epochs", "1", "--eval-seconds", "0.2", "--snr-batches", "2", "--quiet"]
    r = _cli(*args, cwd=REPO, timeout=5400)  # about 40 compiles of tiny programs
    assert r.returncode == 0, r.stderr[-3000:]
    rows = list(csv_rows(out / "results.csv"))
    assert len(rows) == 2 * 4 * 2
    assert all(int(x["iterations"]) == 2 and x["det_reward_per_s"] not in ("", "nan") for x in rows)
    screen = list(csv_rows(out / "screen.csv"))
    assert sum(x["chosen"] == "True" for x in screen) == 3
    snr = list(csv_rows(out / "snr.csv"))
    assert len(snr) == 2 * 4 * 2 and all(float(x["trcov"]) > 0 for x in snr)
    control = list(csv_rows(out / "control.csv"))  # white at 0.02 s with 2x the environments, evaluated
    assert [(x["exploration"], x["control_dt"], x["iterations"]) for x in control] == [("white", "0.02", "2")] * 2
    white = [x for x in rows if x["exploration"] == "white" and x["control_dt"] == "0.02"]
    per_run = {2 * 20 * 8}  # 2 iterations of 20 control steps, 8 environments
    assert {int(x["control_steps"]) for x in control} == {2 * int(x["control_steps"]) for x in white} == per_run
    assert all(x["det_reward_per_s"] not in ("", "nan") for x in control)
    chosen = {r["exploration"]: (r["field"], float(r["value"])) for r in screen if r["chosen"] == "True"}
    for c in es.grid_cells(es.StudySpec(dts=(0.02, 0.01)), chosen):
        for s in range(2):
            p = out / "grid" / f"dt{c.dt:g}" / c.process / "points" / f"s{s}"
            assert (p / "mid" / "compact.npz").exists() and (p / "eval" / "eval.json").exists()
    before = (out / "results.csv").read_text()
    r = _cli(*args, cwd=REPO, timeout=600)  # everything done: nothing runs again
    assert r.returncode == 0, r.stderr[-3000:]
    assert (out / "results.csv").read_text() == before
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["chosen"]) == {"nm-periods", "ou", "colored"}
    assert summary["runs"] == summary["finished_runs"] == 16
    assert len(summary["answers"]["cells"]) == 8 and set(summary["answers"]["best"]) == {"0.02", "0.01"}
    ref = {r["exploration"]: r for r in summary["screen_from_grid"]}  # the grid at the screen's 0.01 s, seed 0
    assert set(ref) == set(es.PROCESSES) and all(r["seed"] == 0 for r in ref.values())
    for r in screen:  # a chosen setting's grid run repeats its screen run (same config, seed, first iteration)
        if r["chosen"] == "True":
            assert float(ref[r["exploration"]]["score"]) == pytest.approx(float(r["score"]), rel=1e-4, abs=1e-4)


def csv_rows(path):
    import csv

    with open(path) as f:
        yield from csv.DictReader(f)


def test_publish_then_seed_a_fresh_directory_carries_what_a_resume_needs(tmp_path):
    """publish copies the tables and every cell's continuation files (not the checkpoints);
    seed_from puts them into a fresh study directory and leaves a cell that is already there alone."""
    src = tmp_path / "runs"
    cell = src / "grid" / "dt0.005" / "ou"
    pt = cell / "points" / "s0"
    files = {cell / "sweep.json": "{}", pt / "config.json": "{}", pt / "metrics.jsonl": "{}\n",
             pt / "compact.npz": "npz", pt / "mid" / "compact.npz": "mid", pt / "mid" / "config.json": "{}",
             pt / "eval" / "eval.json": "{}", pt / "checkpoints" / "40960" / "state" / "x": "ckpt",
             pt / "resumes.jsonl": "", src / "study.json": "{}", src / "results.csv": "a\n",
             src / "control.csv": "c\n", src / "control/dt0.02/white/sweep.json": "{}",
             src / "control/dt0.02/white/points/s0/compact.npz": "ctl"}
    for f, text in files.items():
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(text)
    dest = tmp_path / "published"
    xr.publish(src, dest)
    got = {str(f.relative_to(dest)) for f in dest.rglob("*") if f.is_file()}
    rel = "runs/grid/dt0.005/ou/"
    assert got == {"study.json", "results.csv", "control.csv", "runs/study.json", rel + "sweep.json",
                   *(rel + "points/s0/" + n for n in ("config.json", "metrics.jsonl", "compact.npz",
                                                      "mid/compact.npz", "mid/config.json", "eval/eval.json")),
                   "runs/control/dt0.02/white/sweep.json", "runs/control/dt0.02/white/points/s0/compact.npz"}
    fresh = tmp_path / "fresh"
    seeded = es.seed_from(dest / "runs", fresh)
    assert seeded == [fresh / "control" / "dt0.02" / "white", fresh / "grid" / "dt0.005" / "ou"]
    assert (fresh / "control/dt0.02/white/points/s0/compact.npz").read_text() == "ctl"
    assert (fresh / "grid/dt0.005/ou/points/s0/mid/compact.npz").read_text() == "mid"
    assert (fresh / "study.json").exists()
    (fresh / "grid/dt0.005/ou/points/s0/metrics.jsonl").write_text("newer\n")
    assert es.seed_from(dest / "runs", fresh) == []  # a cell already there is never overwritten
    assert (fresh / "grid/dt0.005/ou/points/s0/metrics.jsonl").read_text() == "newer\n"


def test_best_and_worst_process_and_their_median_seeds():
    rows = [{"control_dt": 0.005, "exploration": p, "seed": s, "avg_reward_per_s": v}
            for p, vals in {"white": [1.0, 5.0, 3.0], "ou": [9.0, 8.0, 7.0, 6.0], "colored": [0.0, 0.5, 0.1]}.items()
            for s, v in enumerate(vals)]
    assert xr.best_and_worst(rows, 0.005, ("white", "ou", "colored")) == [("ou", 2), ("colored", 2)]  # ou: 7.0, the lower median of 4
    assert xr.best_and_worst(rows, 0.005, ("white", "nm-periods")) is None
