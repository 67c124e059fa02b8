"""The first exploration study's record (results/exploration/): its analysis as a function of its
rows, its tables, figures and publisher.

The numbers are checked against independent computations: NumPy means and scipy's t and Welch
intervals; the publisher against the committed files, byte for byte; the answers in words
(docs/exploration-study.md) by their numbers, against scipy's Welch intervals of the committed rows.
"""

from __future__ import annotations

import math
import pathlib
import re
import subprocess
import sys

import numpy as np
import pytest
import scipy.stats

from nmrl.analysis import exploration_answers as xa
from nmrl.analysis import exploration_figures as xf
from nmrl.analysis import exploration_report as xrep
from nmrl.analysis import publish_exploration as pub
from nmrl.explore.spec import KINDS as PROCESSES
from nmrl.runs import store

REPO = pathlib.Path(__file__).resolve().parents[1]
RECORD = REPO / "results" / "exploration"


def _rows(rewards, diverged_at=None, step0=5120):
    return [{"step": step0 * (i + 1), "trials": 10 * (i + 1), "avg_reward": r, "forward_speed": r / 2,
             "diverged": diverged_at is not None and i >= diverged_at} for i, r in enumerate(rewards)]


def test_score_is_the_mean_of_the_second_half_and_diverged_scores_minus_inf():
    assert math.isclose(xa.score(_rows([-5.0, -3.0, -1.0, 2.0])), np.mean([-1.0, 2.0]))
    assert math.isclose(xa.score(_rows([-5.0, -3.0, -1.0])), np.mean([-3.0, -1.0]))  # odd: the later half
    assert xa.score(_rows([1.0, 2.0, 3.0, 4.0], diverged_at=3)) == -math.inf
    assert xa.score([]) == -math.inf


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
    assert xa.choose(rows) == {"ou": ("corr_time_s", 0.09), "colored": ("beta", 0.5)}


def test_answers_match_scipy_t_and_welch_intervals():
    rng = np.random.default_rng(3)
    rows = []
    vals = {}
    for dt in (0.02, 0.005):
        for p in PROCESSES:
            v = rng.normal(2.0 + (p == "nm-periods") - (dt == 0.005) * (p == "white"), 0.4, size=4)
            vals[(dt, p)] = v
            rows += [{"control_dt": dt, "exploration": p, "avg_reward_per_s": x} for x in v]
    a = xa.answers(rows, (0.02, 0.005), PROCESSES)
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
        means = {p: vals[(dt, p)].mean() for p in PROCESSES}
        assert a["best"][f"{dt:g}"] == max(means, key=means.get)
    assert a["process_step_change"] == []  # two control steps: the one change is the coarse-to-fine one


def _welch(x, y):
    vx, vy = x.var(ddof=1) / len(x), y.var(ddof=1) / len(y)
    df = (vx + vy) ** 2 / (vx ** 2 / (len(x) - 1) + vy ** 2 / (len(y) - 1))
    return x.mean() - y.mean(), scipy.stats.t.ppf(0.975, df) * math.sqrt(vx + vy)


def test_each_step_to_the_next_finer_one_is_a_welch_difference_in_the_tables():
    """With 20, 10 and 5 ms every process also has its change 20 → 10 ms and 10 → 5 ms: Welch
    intervals as scipy gives them, a row each in the change table."""
    rng = np.random.default_rng(5)
    level = {0.02: 1.0, 0.01: 3.0, 0.005: 3.05}  # white: a clear gain, then none
    vals, rows = {}, []
    for dt in (0.02, 0.005, 0.01):
        for p in PROCESSES:
            vals[(dt, p)] = v = rng.normal(level[dt], 0.3, size=4)
            rows += [{"control_dt": dt, "exploration": p, "avg_reward_per_s": x} for x in v]
    a = xa.answers(rows, (0.02, 0.005, 0.01), PROCESSES)
    got = {(tuple(x["a"]), tuple(x["b"])): x for x in a["process_step_change"]}
    assert len(got) == 2 * len(PROCESSES)
    for finer, coarser in ((0.01, 0.02), (0.005, 0.01)):
        for p in PROCESSES:
            d, h = _welch(vals[(finer, p)], vals[(coarser, p)])
            x = got[((finer, p), (coarser, p))]
            assert math.isclose(x["diff"], d) and math.isclose(x["ci95"], h, rel_tol=1e-9)
    md = xrep.report({"answers": a, "runs": len(rows), "finished_runs": len(rows)}, [], [], [],
                   (0.02, 0.005, 0.01), PROCESSES, 16)
    d1, h1 = _welch(vals[(0.01, "white")], vals[(0.02, "white")])
    d2, h2 = _welch(vals[(0.005, "white")], vals[(0.01, "white")])
    assert abs(d1) > h1 and abs(d2) < h2
    assert f"| 10 ms − 20 ms | {d1:+.1f} ± {h1:.1f} **(significant)** |" in md
    assert f"| 5 ms − 10 ms | {d2:+.1f} ± {h2:.1f} |" in md


def test_the_control_answers_are_welch_differences_and_its_curves_t_intervals():
    rng = np.random.default_rng(11)
    fine, coarse = 0.005, 0.02
    vals = {k: rng.normal(m, 0.5, size=4) for k, m in (("ctl", 1.0), ("fine", 3.0), ("coarse", 1.2))}
    row = lambda dt, p, v: {"control_dt": dt, "exploration": p, "avg_reward_per_s": v,  # noqa: E731
                            "det_reward_per_s": 2 * v, "auc_reward_per_s": v / 2}
    control = [row(coarse, "white", v) for v in vals["ctl"]]
    grid = [row(fine, "white", v) for v in vals["fine"]] + [row(coarse, "white", v) for v in vals["coarse"]] + \
        [row(fine, "ou", 99.0), row(fine, "ou", 98.0)]
    a = xa.control_answers(control, grid, coarse, fine)
    for key, scale in (("avg_reward_per_s", 1), ("det_reward_per_s", 2), ("auc_reward_per_s", 0.5)):
        for name, other in (("minus_white_fine", "fine"), ("minus_white_coarse", "coarse")):
            d, h = _welch(scale * vals["ctl"], scale * vals[other])
            x = a[key][name]
            assert math.isclose(x["diff"], d) and math.isclose(x["ci95"], h, rel_tol=1e-9)
            assert x["significant"] == (abs(d) > h)
        lo, hi = scipy.stats.t.interval(0.95, 3, loc=scale * vals["ctl"].mean(), scale=scipy.stats.sem(scale * vals["ctl"]))
        assert math.isclose(a[key]["cell"]["ci95"], (hi - lo) / 2, rel_tol=1e-9) and a[key]["cell"]["n"] == 4
    assert xa.control_answers(control[:1], grid, coarse, fine)["avg_reward_per_s"]["minus_white_fine"] is None

    runs = [[{"avg_reward": float(x)} for x in rng.normal(size=n)] for n in (5, 4, 6)]  # 4 iterations in common
    means = xa.iteration_means(runs)
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
    path = xf.draw_control(ctl, tmp_path / "control.png")
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


def test_the_report_shows_each_cell_and_difference_of_the_finished_runs():
    rng = np.random.default_rng(5)
    rows, vals = [], {}
    for dt in (0.02, 0.005):
        for p in PROCESSES:
            v = rng.normal(50 + 10 * (p == "ou"), 5, size=4)
            its = [16, 16, 16, 16] if (dt, p) != (0.005, "colored") else [16, 9, 9, 9]
            vals[(dt, p)] = v[[i for i, n in enumerate(its) if n == 16]]
            rows += [{"control_dt": dt, "exploration": p, "iterations": n, "diverged": False, "avg_reward_per_s": x,
                      "det_reward_per_s": x + 1} for x, n in zip(v, its)]
    done = xa.finished(rows, 16)
    assert len(done) == len(rows) - 3
    summary = {"answers": xa.answers(done, (0.02, 0.005), PROCESSES),
               "answers_deterministic": xa.answers(done, (0.02, 0.005), PROCESSES, key="det_reward_per_s")}
    # no answers_auc: its table is drawn with empty cells
    snr = [{"control_dt": 0.005, "exploration": "ou", "setting": "corr_time_s=0.045", "policy": "initial",
            "step": 0, "trcov": 2.0, "trcov_ci": 0.5, "mean_sq": 0.04, "mean_sq_ci": 0.01, "snr_per_s": 1.953e-4}]
    md = xrep.report(summary, rows, [], snr, (0.02, 0.005), PROCESSES, 16)
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


def test_the_summary_figure_draws_the_finished_seeds_means_intervals_and_snr(tmp_path, saved_figures):
    from matplotlib.container import ErrorbarContainer

    rng = np.random.default_rng(8)
    rows = []
    for dt in (0.02, 0.005):
        for p in PROCESSES:
            for s, n in enumerate((16, 16, 16, 7)):  # seed 3 is not over: not drawn
                rows.append({"control_dt": dt, "exploration": p, "seed": s, "iterations": n, "diverged": False,
                             "avg_reward_per_s": float(rng.normal(40, 9)), "det_reward_per_s": float(rng.normal(60, 9))})
    snr = [{"control_dt": dt, "exploration": "white", "policy": pol, "snr_per_s": v, "trcov": 10 * v,
            "trcov_ci": v} for dt, pol, v in ((0.02, "mid", 3e-3), (0.005, "mid", 1e-3), (0.02, "initial", 2e-3))]
    xf.draw_summary(rows, snr, (0.02, 0.005), PROCESSES, 16, tmp_path / "summary.png")
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
    xf.draw_gaits([(title, f) for title, f, _, _ in files], tmp_path / "both.png")
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


def test_best_and_worst_process_and_their_median_seeds():
    rows = [{"control_dt": 0.005, "exploration": p, "seed": s, "avg_reward_per_s": v}
            for p, vals in {"white": [1.0, 5.0, 3.0], "ou": [9.0, 8.0, 7.0, 6.0], "colored": [0.0, 0.5, 0.1]}.items()
            for s, v in enumerate(vals)]
    assert xa.best_and_worst(rows, 0.005, ("white", "ou", "colored")) == [("ou", 2), ("colored", 2)]  # ou: 7.0, the lower median of 4
    assert xa.best_and_worst(rows, 0.005, ("white", "nm-periods")) is None


def test_the_analysis_is_made_of_finished_runs_only():
    """The study's analysis of its rows: a seed half way through counts as a run but enters no
    answer; a diverged seed is over and enters; the screen's choice is the best mean score."""
    finals = {0: 1.5, 1: 0.5, 2: 9.0, 3: -20.0}
    its = {0: 16, 1: 16, 2: 8, 3: 5}
    rows = [{"control_dt": 0.02, "exploration": "white", "seed": s, "iterations": its[s], "diverged": s == 3,
             "avg_reward_per_s": v / 0.02, "det_reward_per_s": v, "auc_reward_per_s": v} for s, v in finals.items()]
    screen = [{"exploration": "ou", "field": "corr_time_s", "value": v, "score": sc}
              for v, sc in ((0.045, 1.0), (0.09, 2.0), (0.09, 0.5))]
    a = xa.analysis(rows, [], screen, (0.02,), ("white", "ou"), 16)
    assert (a["runs"], a["finished_runs"]) == (4, 3) and "control" not in a
    assert a["chosen"] == {"ou": {"field": "corr_time_s", "value": 0.09}}  # mean 1.25 > 1.0
    (c,) = a["answers"]["cells"]
    v = np.array([finals[0], finals[1], finals[3]]) / 0.02
    lo, hi = scipy.stats.t.interval(0.95, 2, loc=v.mean(), scale=scipy.stats.sem(v))
    assert c["n"] == 3 and math.isclose(c["mean"], v.mean()) and math.isclose(c["ci95"], (hi - lo) / 2)


def test_the_publisher_regenerates_the_committed_record_byte_for_byte(tmp_path):
    """summary.json, answers.md and the three figures made again from the committed tables and runs
    are the committed files."""
    written = pub.publish(RECORD, tmp_path)
    names = sorted(str(p.relative_to(tmp_path)) for p in written)
    assert names == ["answers.md", "control.png", "learning_curves.png", "summary.json", "summary.png"]
    for name in names:
        assert (tmp_path / name).read_bytes() == (RECORD / name).read_bytes(), name


def _cells(rows: list[dict], key: str) -> dict:
    out: dict = {}
    for r in rows:
        out.setdefault((float(r["control_dt"]), r["exploration"]), []).append(float(r[key]))
    return {k: np.array(v) for k, v in out.items()}


def _welch_satterthwaite(samples, weights):
    """sum w_i mean_i and its 95% half-width, written out with numpy and scipy's t quantile."""
    v = [w * w * np.var(x, ddof=1) / len(x) for w, x in zip(weights, samples)]
    df = sum(v) ** 2 / sum(vi ** 2 / (len(x) - 1) for vi, x in zip(v, samples))
    return sum(w * np.mean(x) for w, x in zip(weights, samples)), scipy.stats.t.ppf(0.975, df) * math.sqrt(sum(v))


def test_the_answers_in_words_carry_welch_intervals_of_the_committed_rows():
    """Every 'x ± h' of the answers in words (docs/exploration-study.md) is, to its one decimal, a
    cell's t-interval, a Welch difference of two cells or a Welch-Satterthwaite difference of two
    changes, computed here with scipy from results.csv and control.csv; question 1's first number
    is white 5 ms − 20 ms on the exploring policy."""
    said = "\n".join(pub.words())
    results, control = store.read_csv(RECORD / "results.csv"), store.read_csv(RECORD / "control.csv")
    fmt = lambda d, h: f"{d:+.1f} ± {h:.1f}"  # noqa: E731
    known = set()
    for key in ("avg_reward_per_s", "det_reward_per_s", "auc_reward_per_s"):
        rows = results + [{**r, "exploration": "control"} for r in control]
        c = _cells(rows, key)
        for k, v in c.items():
            lo, hi = scipy.stats.t.interval(0.95, len(v) - 1, loc=v.mean(), scale=scipy.stats.sem(v))
            known.add(fmt(v.mean(), (hi - lo) / 2))
            for k2, v2 in c.items():
                if k2 != k:
                    known.add(fmt(*_welch(v, v2)))
        for a in PROCESSES:
            for b in PROCESSES:
                if a != b:
                    samples = [c[(0.005, a)], c[(0.02, a)], c[(0.005, b)], c[(0.02, b)]]
                    known.add(fmt(*_welch_satterthwaite(samples, [1.0, -1.0, -1.0, 1.0])))
    found = re.findall(r"[+-]\d+\.\d ± \d+\.\d", said)
    assert len(found) == 96 and not set(found) - known, set(found) - known
    white = _cells(results, "avg_reward_per_s")
    q1 = next(ln for ln in said.splitlines() if ln.startswith("1. "))
    assert f"`white` 5 ms − 20 ms: {fmt(*_welch(white[(0.005, 'white')], white[(0.02, 'white')]))} per s" in q1


def test_the_publisher_refuses_a_folder_without_a_study_in_one_line(tmp_path):
    p = subprocess.run([sys.executable, "scripts/publish/publish_exploration.py", "--record", str(tmp_path / "x"),
                        "--dest", str(tmp_path / "out")], cwd=REPO, capture_output=True, text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "--record=" in lines[0] and "study.json" in lines[0], p.stderr
    assert not (tmp_path / "out").exists()
