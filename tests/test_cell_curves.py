"""A study's per-cell statistics and learning-curve bands (nmrl/analysis/cell_curves.py) and the
second exploration study's report (nmrl/experiments/exploration2_analysis.report), against scipy and
numbers computed here from hand-written run files."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from scipy import stats

from nmrl.analysis import cell_curves
from nmrl.experiments import exploration2_analysis, kit


def test_a_cells_summary_is_the_t_interval_and_rliables_iqm():
    x = np.array([-50.0, 12.5, 30.0, 41.0, 44.0, 47.5, 90.0, 300.0])
    s = cell_curves.summary(list(x) + [float("nan")])  # a non-finite value is not a run
    lo, hi = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    assert s["n"] == 8 and s["mean"] == pytest.approx(x.mean()) and s["sd"] == pytest.approx(x.std(ddof=1))
    assert (s["ci_lo"], s["ci_hi"]) == (pytest.approx(lo), pytest.approx(hi))
    assert s["iqm"] == pytest.approx(np.sort(x)[2:6].mean())  # 25% trimmed: 2 of 8 off each end
    assert s["iqm_lo"] < s["iqm"] < s["iqm_hi"] and s["iqm_hi"] - s["iqm_lo"] < x.max() - x.min()


def test_a_summary_leaves_out_what_its_runs_cannot_support():
    assert cell_curves.summary([])["mean"] == ""
    one = cell_curves.summary([3.0])
    assert one["mean"] == 3.0 and one["sd"] == "" and one["ci_lo"] == ""
    three = cell_curves.summary([1.0, 2.0, 6.0])
    assert three["sd"] == pytest.approx(np.std([1, 2, 6], ddof=1)) and three["iqm"] == ""


def test_a_band_is_the_mean_and_t_interval_over_seeds_on_their_common_points():
    t = np.arange(1, 6) * 102.4
    ys = [np.array([1.0, 2.0, 4.0, 8.0, 9.0]), np.array([0.0, 3.0, 3.0, 6.0]), np.array([2.0, 1.0, 5.0, 7.0, 1.0])]
    tt, mean, lo, hi = cell_curves.band([(t[:len(y)], y) for y in ys])
    assert np.array_equal(tt, t[:4])  # the shortest seed's length
    for j in range(4):
        col = np.array([y[j] for y in ys])
        a, b = stats.t.interval(0.95, 2, loc=col.mean(), scale=stats.sem(col))
        assert (mean[j], lo[j], hi[j]) == (pytest.approx(col.mean()), pytest.approx(a), pytest.approx(b))
    with pytest.raises(ValueError, match="same time points"):
        cell_curves.band([(t, ys[0]), (t * 2, ys[2])])


def _point(root, cell, name, cfg, rows):
    d = root / cell / "points" / name
    d.mkdir(parents=True)
    (d / "config.json").write_text(json.dumps(cfg))
    (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_the_report_tabulates_every_cell_at_its_budget_and_draws_the_curves(tmp_path):
    rows = []
    for seed, det in ((100, -40.0), (101, -50.0)):  # a screen cell, one value, 2 seeds at budget
        _point(tmp_path, "screen/sigma/dt0.02/white", f"sigma0.4_s{seed}", {"control_dt": 0.02},
               [{"step": 5120, "avg_reward": -1.0}, {"step": 10240, "avg_reward": -0.5}])
        rows.append({"cell": "screen/sigma/dt0.02/white", "point": f"sigma0.4_s{seed}", "field": "sigma",
                     "value": 0.4, "steps": 10240, "budget": 10240, "diverged": False, "det_reward_per_s": det})
    dets = [10.0, 30.0, 20.0, 60.0]
    for seed, det in enumerate(dets):  # a grid cell of 4 seeds, one of them unfinished
        _point(tmp_path, "grid/dt0.0025/white", f"s{seed}", {"control_dt": 0.0025},
               [{"step": 40960, "avg_reward": 0.1 * seed}])
        rows.append({"cell": "grid/dt0.0025/white", "point": f"s{seed}", "field": "", "value": "",
                     "steps": 40960 if seed < 3 else 100, "budget": 40960, "diverged": False,
                     "det_reward_per_s": det})
    # a run that diverged has ended: it counts, scored by its last good policy, and is counted as diverged
    _point(tmp_path, "grid/dt0.0025/white", "s4", {"control_dt": 0.0025}, [{"step": 40960, "avg_reward": 0.0}])
    rows.append({"cell": "grid/dt0.0025/white", "point": "s4", "field": "", "value": "", "steps": 200,
                 "budget": 40960, "diverged": "True", "det_reward_per_s": 0.0})
    exploration2_analysis.report(rows, tmp_path)
    table = {r["cell"]: r for r in csv.DictReader(open(tmp_path / exploration2_analysis.CELLS_CSV))}
    screen, grid = table["screen/sigma/dt0.02/white"], table["grid/dt0.0025/white"]
    assert screen["value"] == "0.4" and screen["n"] == "2" and float(screen["mean"]) == pytest.approx(-45.0)
    assert grid["n"] == "4" and float(grid["mean"]) == pytest.approx(15.0)
    assert float(grid["iqm"]) == pytest.approx(15.0)  # 0, 10, 20, 30 less one from each end
    assert (screen["diverged"], grid["diverged"]) == ("0", "1")
    assert (tmp_path / exploration2_analysis.SCREEN_FIGURE).stat().st_size > 0
    assert (tmp_path / exploration2_analysis.GRID_FIGURE).stat().st_size > 0
    t, y = kit.learning_curve(tmp_path / "screen/sigma/dt0.02/white/points/sigma0.4_s100")
    assert np.allclose(t, [102.4, 204.8]) and np.allclose(y, [-50.0, -25.0])  # per second: r / 0.02 s


def test_the_grids_learning_curves_are_panels_by_control_step_coarsest_first(tmp_path, saved_figures):
    """Cells that ran finest step first are drawn 20, 5, 2.5 ms left to right, each panel's arms in
    the study's arm order whatever order their rows come in."""
    rows = []
    for cell, dt in (("grid/dt0.0025/nmp", 0.0025), ("grid/dt0.0025/white", 0.0025), ("grid/dt0.02/white", 0.02),
                     ("grid/dt0.005/white", 0.005)):
        _point(tmp_path, cell, "s0", {"control_dt": dt}, [{"step": 100, "avg_reward": 0.1}])
        rows.append({"cell": cell, "point": "s0", "field": "", "value": "", "steps": 100, "budget": 100,
                     "diverged": False, "det_reward_per_s": 1.0})
    exploration2_analysis.report(rows, tmp_path)
    (fig,) = [f for p, f in saved_figures if p.name == exploration2_analysis.GRID_FIGURE]
    axes = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in axes] == ["control step 20 ms", "control step 5 ms", "control step 2.5 ms"]
    assert [t.get_text() for t in axes[2].get_legend().get_texts()] == ["white (1)", "nmp (1)"]


def test_the_asymptotes_curves_and_ws_sigma_sensitivity_are_drawn_from_their_runs(tmp_path, saved_figures):
    """The asymptote's runs are drawn as curves, one line per arm (white first), against simulated
    seconds; W's sigma sensitivity as every ended run of W at 2.5 ms by sigma (read from the points'
    configs), smallest first, the grid's cell marked, each cell's mean at its marker; a run still
    going is left out."""
    rows = []
    for cell, sigma, dets in (("asymptote/dt0.005/colored", 0.4, (1.0, 2.0)),
                              ("asymptote/dt0.005/white", 1.0, (3.0, 5.0)),
                              ("sensitivity/dt0.0025/white_sigma2.5", 2.5, (50.0, 70.0, 0.0)),
                              ("grid/dt0.0025/white", 1.0, (100.0, 120.0)),
                              ("sensitivity/dt0.0025/white_sigma0.4", 0.4, (10.0, 30.0))):
        dt = 0.005 if cell.startswith("asymptote/") else 0.0025
        for seed, det in enumerate(dets):
            _point(tmp_path, cell, f"s{seed}", {"control_dt": dt, "sigma": sigma},
                   [{"step": 100, "avg_reward": 0.1}, {"step": 200, "avg_reward": 0.2 + seed}])
            going = seed == 2
            rows.append({"cell": cell, "point": f"s{seed}", "field": "", "value": "", "steps": 100 if going else 200,
                         "budget": 200, "diverged": False, "det_reward_per_s": det})
    exploration2_analysis.report(rows, tmp_path)
    figs = {p.name: f for p, f in saved_figures}
    (ax,) = [a for a in figs[exploration2_analysis.ASYMPTOTE_FIGURE].axes if a.get_visible()]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["white (2)", "colored (2)"]
    assert ax.get_xlabel() == "simulated seconds per environment"
    (ax,) = figs[exploration2_analysis.SENSITIVITY_FIGURE].axes
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert labels == ["σ = 0.4\n(n=2)", "σ = 1 (grid)\n(n=2)", "σ = 2.5\n(n=2)"]
    assert [y for _, y, _ in _bars(ax)] == [20.0, 110.0, 60.0]


def _bars(ax):
    """Each errorbar of ``ax``: (its marker's x, y, the bar's two ends)."""
    out = []
    for c in ax.containers:
        (x,), (y,) = c.lines[0].get_data()
        seg = c.lines[2][0].get_segments()[0]
        out.append((float(x), float(y), seg))
    return out


def test_the_contrast_figure_draws_each_welch_interval_against_the_margin(tmp_path, saved_figures):
    from nmrl.analysis import contrast_figures, prereg_stats

    a, b, c = [12.0, 30.0, 25.0, 41.0, 19.0], [5.0, 9.0, -3.0, 14.0, 2.0, 7.0], [40.0, 90.0, 70.0]
    table = prereg_stats.family({"a": a, "b": b, "c": c}, (("X1", {"a": 1.0, "b": -1.0}),
                                                          ("X2", {"c": 1.0, "b": -1.0})), 50.0)
    table.append({"contrast": "X3", "decision": "pending"})  # no estimate: listed, not drawn
    contrast_figures.contrasts(table, 50.0, tmp_path / "c.png", "difference")
    assert (tmp_path / "c.png").stat().st_size > 0
    ax = saved_figures[0][1].axes[0]
    bars = sorted(_bars(ax), key=lambda t: -t[1])  # top row first
    assert len(bars) == 2
    for (x, _, seg), (p, q) in zip(bars, ((a, b), (c, b))):
        ci = stats.ttest_ind(p, q, equal_var=False).confidence_interval(0.95)
        assert x == pytest.approx(np.mean(p) - np.mean(q))
        assert sorted([seg[0][0], seg[1][0]]) == [pytest.approx(ci.low), pytest.approx(ci.high)]
    rows = [t.get_text() for _, t in sorted(zip(ax.get_yticks(), ax.get_yticklabels()), key=lambda p: -p[0])]
    assert [r.split(":")[0] for r in rows] == ["X1", "X2", "X3"] and rows[2] == "X3: pending"  # top to bottom
    (band,) = ax.patches  # the equivalence band, in data units along x
    assert (band.get_x(), band.get_x() + band.get_width()) == (-50.0, 50.0)


def test_the_endpoint_figure_draws_every_run_and_each_cells_t_interval(tmp_path, saved_figures):
    from nmrl.analysis import contrast_figures

    w, n = [-40.0, -55.0, -47.5, -60.0], [10.0, float("nan"), 30.0, -5.0]
    contrast_figures.endpoints({"control step 2.5 ms": {"white": w, "nmp": n}}, tmp_path / "e.png", "reward per s",
                               colors={"nmp": "C5"})
    ax = saved_figures[0][1].axes[0]
    assert [c.lines[0].get_color() for c in ax.containers] == ["tab:blue", "C5"]  # a cell's colour, else blue
    for (x, y, seg), v in zip(_bars(ax), (w, [10.0, 30.0, -5.0])):
        ci = stats.t.interval(0.95, len(v) - 1, loc=np.mean(v), scale=stats.sem(v))
        assert y == pytest.approx(np.mean(v))
        assert sorted([seg[0][1], seg[1][1]]) == [pytest.approx(ci[0]), pytest.approx(ci[1])]
    dots = [ln for ln in ax.lines if ln.get_marker() == "o" and len(ln.get_ydata()) > 1]
    assert [sorted(ln.get_ydata()) for ln in dots] == [sorted(w), [-5.0, 10.0, 30.0]]
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert labels == ["white\n(n=4)", "nmp\n(n=3, 1 non-finite)"]


def test_the_paired_figure_draws_every_runs_pair_and_the_diagonal(tmp_path, saved_figures):
    from nmrl.analysis import contrast_figures

    w, n = [(1.9, 2.0), (0.5, 0.6)], [(0.9, 0.02), (float("nan"), 0.1), (0.8, 0.05)]
    contrast_figures.paired({"control step 20 ms": {"white": w, "nmp": n}}, tmp_path / "s.png", "noisy", "det")
    ax = saved_figures[0][1].axes[0]
    diag, *series = ax.lines
    assert np.allclose(diag.get_xdata(), diag.get_ydata())  # y = x
    assert min(diag.get_xdata()) < 0.02 and max(diag.get_xdata()) > 2.0  # spans every pair
    assert [list(zip(ln.get_xdata(), ln.get_ydata())) for ln in series] == [w, [(0.9, 0.02), (0.8, 0.05)]]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["y = x", "white (n=2)", "nmp (n=2)"]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("noisy", "det")
    # colours given per cell hold in every panel, whatever the cells before them
    contrast_figures.paired({"20 ms": {"white": w, "nmp": n}, "2.5 ms": {"nmp": n}}, tmp_path / "t.png", "x", "y",
                            colors={"white": "C0", "nmp": "C5"})
    first, second = saved_figures[1][1].axes[:2]
    assert [ln.get_color() for ln in first.lines[1:]] == ["C0", "C5"] and second.lines[1].get_color() == "C5"


def test_the_report_draws_the_endpoints_and_contrasts_once_grid_cells_exist(tmp_path):
    rows = [{"cell": "screen/sigma/dt0.02/white", "point": f"sigma0.4_s{s}", "field": "sigma", "value": 0.4,
             "steps": 10, "budget": 10, "diverged": False, "det_reward_per_s": -45.0 + s} for s in (100, 101)]
    exploration2_analysis.report(rows, tmp_path)
    assert not (tmp_path / exploration2_analysis.ENDPOINT_FIGURE).exists()
    assert not (tmp_path / exploration2_analysis.CONTRAST_FIGURE).exists()
    for dt, base in ((0.02, 100.0), (0.0025, 60.0)):
        rows += [{"cell": f"grid/dt{dt:g}/white", "point": f"s{s}", "field": "", "value": "", "steps": 10,
                  "budget": 10, "diverged": False, "det_reward_per_s": base + 7.0 * s} for s in range(3)]
    exploration2_analysis.report(rows, tmp_path)
    assert (tmp_path / exploration2_analysis.ENDPOINT_FIGURE).stat().st_size > 0
    assert (tmp_path / exploration2_analysis.CONTRAST_FIGURE).stat().st_size > 0  # P1 has its estimate
    assert not (tmp_path / exploration2_analysis.SPEED_FIGURE).exists()  # no run has both speeds
    rows = [dict(r, forward_speed=0.5, det_forward_speed=0.4) for r in rows]
    exploration2_analysis.report(rows, tmp_path)
    assert (tmp_path / exploration2_analysis.SPEED_FIGURE).stat().st_size > 0


def test_the_curves_figure_draws_each_cells_mean_and_t_band_in_its_colour(tmp_path, saved_figures):
    t = np.array([1.0, 2.0, 3.0])
    w = [(t, np.array([1.0, 2.0, 4.0])), (t, np.array([3.0, 2.0, 6.0])), (t, np.array([2.0, 5.0, 5.0]))]
    n = [(t, np.array([0.0, 1.0, 1.0])), (t, np.array([1.0, 0.0, 2.0])), (t, np.array([2.0, 2.0, 0.0]))]
    cell_curves.figure({"20 ms": {"white": w, "nmp": n}, "2.5 ms": {"nmp": n}}, tmp_path / "f.png", "reward",
                       colors={"white": "C0", "nmp": "C5"})
    first, second = saved_figures[0][1].axes[:2]
    (mw, mn), (mn2,) = first.lines, second.lines
    assert np.allclose(mw.get_ydata(), np.mean([y for _, y in w], axis=0))
    assert (mw.get_color(), mn.get_color(), mn2.get_color()) == ("C0", "C5", "C5")
    band = first.collections[0].get_paths()[0].vertices[:, 1]  # the t band of white, 95%
    half = stats.t.ppf(0.975, 2) * np.std([y for _, y in w], axis=0, ddof=1) / np.sqrt(3)
    assert band.max() == pytest.approx(np.max(mw.get_ydata() + half))
    assert band.min() == pytest.approx(np.min(mw.get_ydata() - half))
