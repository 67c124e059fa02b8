"""The third study's design and analysis (docs/thesis-actor-critic.md, nmrl/experiments/thesis_ac.py)
against independent computations: the cells against the continuous-time rules written out, the
family's decisions against scipy's Welch test and Holm's procedure by hand, and the page's numbers
from Fig. 3's committed metrics and scipy's noncentral t."""
from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest
import scipy.stats

from nmrl.experiments import thesis_ac
from nmrl.experiments.thesis_ac_cells import CELLS, DTS
from tests.doc_numbers import assert_numbers

REPO = pathlib.Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "thesis-actor-critic.md"


def _doc() -> str:
    return DOC.read_text()


@pytest.mark.parametrize("dt", DTS)
def test_every_point_is_the_20_ms_learner_held_in_seconds(dt):
    cell = next(c for c in CELLS if c.name == f"grid/dt{dt:g}")
    k = dt / 0.02
    steps = cell.steps
    assert steps * 32 * dt == pytest.approx(1e5)  # 10^5 simulated seconds per point
    assert len(cell.points) == 24 and sorted({p["seed"] for p in cell.points}) == list(range(8))
    for p in cell.points:
        arm = p["name"].rsplit("_s", 1)[0]
        period = {"stationary": dt, "p0.1s": 0.1, "p0.2s": 0.2}[arm]
        assert p.get("l", 10) == round(period / dt)
        assert p.get("gamma", 0.995) == pytest.approx(0.995 ** k, rel=1e-12)
        assert p.get("alpha", 0.8) == pytest.approx(0.8 ** k, rel=1e-12)
        assert p.get("stop_prob", 1 / 250) == pytest.approx(k / 250, rel=1e-12)
        assert p.get("reward_scale", 1.0) == pytest.approx(k)
        assert p.get("lam", 0.5) == pytest.approx(0.5 ** k if arm == "stationary" else 0.5)
        assert p.get("delta", 4) == round(4 / k)
        assert p["physics"] == "c" and p["physics_timestep"] == 0.0025 and p["num_envs"] == 32
        assert p.get("chunk_steps", 250) * dt == pytest.approx(10.0)
        assert "beta_theta" not in p and "beta_v" not in p and "preset" not in p  # the paper's step sizes


def _rows(rng, means: dict[tuple[str, float], tuple[float, float]], n: int = 8) -> list[dict]:
    rows = []
    for (arm, dt), (auc, det) in means.items():
        for s in range(n):
            rows.append({"cell": f"grid/dt{dt:g}", "point": f"{arm}_s{s}", "control_dt": str(dt), "steps": "1",
                         "budget": "1", "diverged": "False", "auc_reward_per_s": str(auc + 10 * rng.normal()),
                         "det_reward_per_s": str(det + 40 * rng.normal())})
    return rows


def _holm(p: list[float]) -> list[float]:
    order = np.argsort(p)
    adj, running = np.empty(len(p)), 0.0
    for i, j in enumerate(order):
        running = max(running, min(1.0, (len(p) - i) * p[j]))
        adj[j] = running
    return list(adj)


def test_the_family_is_welch_and_holm_over_both_endpoints():
    rng = np.random.default_rng(0)
    means = {("stationary", 0.02): (0, 50), ("p0.1s", 0.02): (60, 60), ("p0.2s", 0.02): (50, 55),
             ("stationary", 0.0025): (-40, 0), ("p0.1s", 0.0025): (60, 60), ("p0.2s", 0.0025): (55, 50)}
    rows = _rows(rng, means)
    fam = thesis_ac.family(rows, 0.0025)
    assert len(fam) == 14 and {r["decision"] for r in fam} <= {"ahead", "behind", "equivalent", "not detected"}
    by = {}
    for r in rows:
        by.setdefault((r["point"].rsplit("_s", 1)[0], float(r["control_dt"])), []).append(r)
    ps = []
    for r in fam:
        x = lambda arm, dt: np.array([float(q[r["endpoint"]]) for q in by[arm, dt]])  # noqa: E731
        if r["contrast"] == "T1":
            t = scipy.stats.ttest_ind(x("stationary", 0.0025), x("stationary", 0.02), equal_var=False)
            assert r["p"] == pytest.approx(t.pvalue, rel=1e-9)
            assert r["estimate"] == pytest.approx(x("stationary", 0.0025).mean() - x("stationary", 0.02).mean())
        if r["contrast"] == "T2":
            t = scipy.stats.ttest_ind(x("p0.1s", 0.0025), x("stationary", 0.0025), equal_var=False)
            lo, hi = t.confidence_interval(0.95)
            assert (r["lo"], r["hi"]) == pytest.approx((lo, hi), rel=1e-9)
        ps.append(r["p"])
    assert [r["p_holm"] for r in fam] == pytest.approx(_holm(ps))
    t1 = {r["endpoint"]: r for r in fam if r["contrast"] == "T1"}
    assert t1["auc_reward_per_s"]["decision"] == "behind"  # -40 against 0, SD 10, 8 seeds
    for r in fam:  # the stratified bootstrap interval beside Welch's (tests/test_prereg_stats.py checks it)
        assert r["lo"] < r["boot_lo"] < r["estimate"] < r["boot_hi"] < r["hi"]


def test_each_cells_summary_is_its_runs_mean_sd_and_iqm():
    """cells.csv's rows: per complete cell and endpoint the mean, SD and rliable's IQM (the 25%
    trimmed mean, scipy) of its runs, with the IQM's bootstrap interval around it."""
    rng = np.random.default_rng(2)
    rows = _rows(rng, {("stationary", 0.02): (0, 50), ("p0.1s", 0.02): (60, 60)})
    summary = {(r["cell"], r["endpoint"]): r for r in thesis_ac.cell_summaries(rows)}
    assert len(summary) == 4
    for (cell, key), r in summary.items():
        arm = cell.split("@")[0]
        x = np.array([float(q[key]) for q in rows if q["point"].rsplit("_s", 1)[0] == arm])
        assert r["n"] == 8 and r["mean"] == pytest.approx(x.mean()) and r["sd"] == pytest.approx(x.std(ddof=1))
        assert r["iqm"] == pytest.approx(scipy.stats.trim_mean(x, 0.25)) and r["iqm_lo"] < r["iqm"] < r["iqm_hi"]


def test_a_family_with_an_unfinished_cell_is_pending():
    rng = np.random.default_rng(1)
    rows = _rows(rng, {("stationary", 0.02): (0, 0), ("p0.1s", 0.02): (1, 1), ("p0.2s", 0.02): (1, 1),
                       ("stationary", 0.0025): (0, 0), ("p0.1s", 0.0025): (1, 1), ("p0.2s", 0.0025): (1, 1)})
    rows[-1]["steps"] = "0"  # the last point of the 2.5 ms cell has not ended
    assert {r["decision"] for r in thesis_ac.family(rows, 0.0025)} == {"pending"}


def test_the_pages_fig3_numbers_are_the_committed_runs():
    """The mean exploring reward per second over the first 2*10^4 trials of Fig. 3's 20 ms runs."""
    doc = _doc()
    for l in (1, 5, 10):
        auc = []
        for s in range(3):
            m = [json.loads(x) for x in (REPO / "results" / "fig3_paper" / "points" / f"l{l}_s{s}" /
                                         "metrics.jsonl").read_text().splitlines() if x.strip()]
            auc.append(np.mean([r["avg_reward"] for r in m if r["trials"] <= 20000]) / 0.02)
        mean, sd = np.mean(auc), np.std(auc, ddof=1)
        assert_numbers(doc, [f"{mean:.1f}", f"{sd:.1f}"], window=20)


def test_the_pages_detectable_differences_are_the_noncentral_t():
    """8 seeds, SD 11, 80% power at alpha / 14: the smallest whole difference of two cells and of an
    interaction of four, by scipy's noncentral t."""
    doc = _doc()
    ds = []
    for cells in (2, 4):
        dof = cells * 7
        tc = scipy.stats.t.ppf(1 - 0.05 / 14 / 2, dof)

        def power(delta):
            nc = delta / (11 * np.sqrt(cells / 8))
            return scipy.stats.nct.sf(tc, dof, nc) + scipy.stats.nct.cdf(-tc, dof, nc)

        ds.append(str(next(d for d in range(1, 200) if power(d) >= 0.8)))
    assert_numbers(doc, ds, window=60)


def test_the_20_ms_cells_progress_numbers_are_the_published_rows():
    """The Progress section's description of the finished 20 ms cell: per arm the mean (SD) of the
    deterministic endpoint and of the AUC over its 8 seeds, recomputed with NumPy from rows.csv, and
    the range of forward speeds of the walking runs (the one that does not walk named apart)."""
    import csv

    path = REPO / "results" / "thesis_ac" / "rows.csv"
    with open(path, newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["cell"] == "grid/dt0.02"]
    if len(rows) < 24:
        pytest.skip("the 20 ms cell is not published in full")
    doc = _doc()
    speeds = []
    for arm in ("stationary", "p0.1s", "p0.2s"):
        rs = [r for r in rows if r["point"].rsplit("_s", 1)[0] == arm]
        assert len(rs) == 8
        for key in ("det_reward_per_s", "auc_reward_per_s"):
            v = np.array([float(r[key]) for r in rs])
            assert_numbers(doc, [f"{v.mean():.1f}", f"{v.std(ddof=1):.1f}"], window=10)
        speeds += [float(r["det_forward_speed"]) for r in rs]
    walking = sorted(v for v in speeds if v >= 1.0)
    assert len(walking) == 23
    assert_numbers(doc, [f"{walking[0]:.2f}", f"{walking[-1]:.2f}", f"{min(speeds):.2f}"], window=200)


def _published(name: str) -> list[dict]:
    import csv

    with open(REPO / "results" / "thesis_ac" / name, newline="") as fh:
        return list(csv.DictReader(fh))


def _welch_contrast(samples, weights, margin):
    """A linear contrast of independent cell means by hand: estimate, Welch-Satterthwaite dof, 95%
    interval, two-sided p, and the TOST p within ``margin`` (the larger of the two one-sided p's)."""
    v = [w * w * x.var(ddof=1) / x.size for w, x in zip(weights, samples)]
    se = np.sqrt(sum(v))
    dof = sum(v) ** 2 / sum(vi**2 / (x.size - 1) for vi, x in zip(v, samples))
    d = sum(w * x.mean() for w, x in zip(weights, samples))
    h = scipy.stats.t.ppf(0.975, dof) * se
    tost = max(scipy.stats.t.sf((d + margin) / se, dof), scipy.stats.t.cdf((d - margin) / se, dof))
    return d, d - h, d + h, 2 * scipy.stats.t.sf(abs(d) / se, dof), tost


#: the page's contrasts T1-T7 written out again: (arm, control step, weight) per cell
_S, _A, _B = "stationary", "p0.1s", "p0.2s"
_WRITTEN = {"T1": [(_S, .0025, 1), (_S, .02, -1)], "T2": [(_A, .0025, 1), (_S, .0025, -1)],
            "T3": [(_B, .0025, 1), (_S, .0025, -1)],
            "T4": [(_A, .0025, 1), (_S, .0025, -1), (_A, .02, -1), (_S, .02, 1)],
            "T5": [(_B, .0025, 1), (_S, .0025, -1), (_B, .02, -1), (_S, .02, 1)],
            "T6": [(_A, .0025, 1), (_A, .02, -1)], "T7": [(_B, .0025, 1), (_B, .02, -1)]}
_MARGINS = {"auc_reward_per_s": 25.0, "det_reward_per_s": 50.0}  #: the page's TOST margins


def _check_rows(rows: list[dict], factor: str) -> list[dict]:
    """The rows of the check's stationary cell with both step sizes times ``factor`` ("3", "0.333")."""
    return [r for r in rows if r["cell"] == "check/dt0.0025" and r["point"].rsplit("_s", 1)[0] == f"stationary_x{factor}"]


def _runs(rows: list[dict], key: str, arm: str, dt: float) -> np.ndarray:
    """The values of ``key`` of ``arm``'s runs in the grid cell at ``dt``."""
    return np.array([float(r[key]) for r in rows if r["cell"] == f"grid/dt{dt:g}"
                     and r["point"].rsplit("_s", 1)[0] == arm])


@pytest.mark.record
@pytest.mark.parametrize("family, fine", [("primary", 0.0025), ("secondary", 0.005)])
def test_the_published_family_is_the_welch_and_holm_of_the_published_rows(family, fine):
    """analysis.csv's primary (2.5 ms) and secondary (5 ms) family recomputed from rows.csv alone:
    each of T1-T7 on both endpoints by hand from the runs' values (the page's contrasts written out
    again here, with 5 ms in place of 2.5 ms for the secondary), Holm over each family's 14 by hand,
    and the decisions by the page's words."""
    fam = [r for r in _published("analysis.csv") if r["family"] == family and r["contrast"] != "the thesis"]
    if any(r["decision"] == "pending" for r in fam):
        pytest.skip(f"the {family} family is not decided in the published rows")
    rows = _published("rows.csv")

    def x(key, arm, dt):
        return _runs(rows, key, arm, fine if dt == 0.0025 else dt)

    written = _WRITTEN
    assert sorted({r["contrast"] for r in fam}) == sorted(written) and len(fam) == 14
    margins = _MARGINS
    ps, tosts = [], []
    for r in fam:
        cells = written[r["contrast"]]
        samples = [x(r["endpoint"], arm, dt) for arm, dt, _ in cells]
        assert all(v.size == 8 for v in samples)
        d, lo, hi, p, tost = _welch_contrast(samples, [w for *_, w in cells], margins[r["endpoint"]])
        assert float(r["tost_p"]) == pytest.approx(tost, rel=1e-9)
        tosts.append(tost)
        assert [float(r[k]) for k in ("estimate", "lo", "hi", "p")] == pytest.approx([d, lo, hi, p], rel=1e-9)
        if len(cells) == 2:
            assert p == pytest.approx(scipy.stats.ttest_ind(samples[0], samples[1], equal_var=False).pvalue)
        ps.append(p)
    for r, ph, th in zip(fam, _holm(ps), _holm(tosts)):
        assert float(r["p_holm"]) == pytest.approx(ph, rel=1e-9)
        assert float(r["tost_p_holm"]) == pytest.approx(th, rel=1e-9)
        assert r["decision"] == (("ahead" if float(r["estimate"]) > 0 else "behind") if ph <= 0.05
                                 else "equivalent" if th <= 0.05 else "not detected")


@pytest.mark.record
def test_the_published_step_size_check_is_the_welch_of_the_published_rows():
    """The check's rows recomputed from rows.csv: each scaled stationary cell at 2.5 ms (4 runs)
    minus the grid's stationary(2.5) (8 runs), by scipy's Welch test, and the page's reading of it
    (an estimate above the endpoint's margin makes T1-T5 conditional)."""
    out = [r for r in _published("analysis.csv") if r["family"] == "check"]
    reading = [r["decision"] for r in out if r["contrast"] == thesis_ac.STEP_SIZE_ROW]
    if reading != ["conditional"] and reading != ["unconditional"]:
        pytest.skip("the step-size check is not complete in the published rows")
    rows = _published("rows.csv")
    base = {key: _runs(rows, key, _S, 0.0025) for key in _MARGINS}
    above = False
    for factor in ("3", "0.333"):
        scaled = {key: np.array([float(r[key]) for r in _check_rows(rows, factor)]) for key in _MARGINS}
        for key, margin in _MARGINS.items():
            (r,) = [r for r in out if r["endpoint"] == key and r["contrast"] == f"step sizes x{factor}"]
            assert scaled[key].size == 4 and base[key].size == 8
            d, lo, hi, p, _ = _welch_contrast([scaled[key], base[key]], [1, -1], margin)
            assert p == pytest.approx(scipy.stats.ttest_ind(scaled[key], base[key], equal_var=False).pvalue)
            assert [float(r[k]) for k in ("estimate", "lo", "hi", "p")] == pytest.approx([d, lo, hi, p], rel=1e-9)
            above |= d > margin
    assert reading == ["conditional" if above else "unconditional"]


def test_the_report_draws_each_endpoints_contrasts_once_its_family_has_estimates(tmp_path):
    rng = np.random.default_rng(3)
    means = {("stationary", 0.02): (0, 50), ("p0.1s", 0.02): (60, 60), ("p0.2s", 0.02): (50, 55)}
    thesis_ac.report(_rows(rng, means), tmp_path)
    assert (tmp_path / thesis_ac.CELLS_CSV).is_file() and (tmp_path / thesis_ac.ENDPOINT_FIGURE).is_file()
    assert not any((tmp_path / f).exists() for f, _ in thesis_ac.CONTRAST_FIGURES.values())  # no 2.5 ms cell
    means.update({("stationary", 0.0025): (-40, 0), ("p0.1s", 0.0025): (60, 60), ("p0.2s", 0.0025): (55, 50)})
    thesis_ac.report(_rows(rng, means), tmp_path)
    assert all((tmp_path / f).stat().st_size > 0 for f, _ in thesis_ac.CONTRAST_FIGURES.values())


@pytest.mark.record
def test_the_published_20_ms_cell_is_complete_though_its_last_chunk_passes_the_budget():
    """Each point of the 20 ms cell ran 313 chunks of 500 steps (156,500 steps against the budget of
    156,250: 3125 s per environment is 312.5 chunks of 10 s), and the cell counts as complete."""
    rows = [r for r in _published("rows.csv") if r["cell"] == "grid/dt0.02"]
    assert len(rows) == 24 and {(r["steps"], r["budget"]) for r in rows} == {("156500", "156250")}
    by = thesis_ac.cells(rows, "det_reward_per_s")
    assert sorted(by) == ["p0.1s@0.02", "p0.2s@0.02", "stationary@0.02"] and {len(v) for v in by.values()} == {8}


@pytest.mark.record
def test_a_points_secondary_measures_are_read_from_its_published_metrics():
    """The last 10% of a 313-chunk run is its last 31 chunks; the reward per step over 20 ms is the
    reward per second; the actor's norm is the last chunk's."""
    point = REPO / "results" / "thesis_ac" / "grid" / "dt0.02" / "points" / "p0.1s_s0"
    m = [json.loads(line) for line in (point / "metrics.jsonl").read_text().splitlines()]
    assert len(m) == 313
    got = thesis_ac.point_secondary(point)
    assert got["last10_reward_per_s"] == pytest.approx(np.mean([r["avg_reward"] for r in m[-31:]]) / 0.02)
    assert got["theta_norm"] == m[-1]["theta_norm"]


def _decided(auc: dict[str, str], det: dict[str, str]) -> list[dict]:
    rest = {f"T{i}": "not detected" for i in range(1, 8)}
    return [{"endpoint": e, "contrast": t, "decision": d}
            for e, given in (("auc_reward_per_s", auc), ("det_reward_per_s", det)) for t, d in {**rest, **given}.items()]


@pytest.mark.parametrize("auc, det, reading", [
    ({"T1": "behind", "T5": "ahead"}, {}, "holds"),  # on one endpoint: stationary loses, the lead grows
    ({"T1": "behind", "T4": "ahead"}, {"T7": "behind"}, "mixed"),  # a period loses its power on the other
    ({"T1": "behind"}, {"T4": "ahead"}, "mixed"),  # the two halves on different endpoints
    ({}, {}, "fails"),
    ({"T2": "ahead", "T6": "equivalent"}, {"T3": "ahead"}, "fails"),  # leads that do not grow do not count
    ({"T1": "behind"}, {}, "mixed"),
])
def test_the_thesis_is_read_from_the_decisions_as_the_page_words_it(auc, det, reading):
    assert thesis_ac.verdict(_decided(auc, det)) == reading


def test_the_thesis_waits_for_its_family():
    fam = _decided({}, {})
    fam[3]["decision"] = "pending"
    assert thesis_ac.verdict(fam) == "pending"


def _checked(auc: tuple[float, float], det: tuple[float, float]) -> list[dict]:
    """Check rows with the given estimates (x3, x1/3) on each endpoint."""
    return [{"endpoint": e, "contrast": f"step sizes x{f}", "estimate": v, "decision": "reported"}
            for e, vs in (("auc_reward_per_s", auc), ("det_reward_per_s", det)) for f, v in zip((3, 0.333), vs)]


@pytest.mark.parametrize("auc, det, reading", [
    ((24.9, -80.0), (49.9, 10.0), "unconditional"),  # within both margins (+25 AUC, +50 det.)
    ((25.1, -80.0), (0.0, 0.0), "conditional"),  # x3 beats by more than the AUC's margin
    ((0.0, 0.0), (-10.0, 50.5), "conditional"),  # x1/3 beats by more than the deterministic margin
    ((-90.0, -60.0), (-120.0, -51.0), "unconditional"),  # worse by more than the margin does not count
])
def test_the_step_size_check_is_read_as_the_page_words_it(auc, det, reading):
    assert thesis_ac.step_size_reading(_checked(auc, det)) == reading


def test_the_step_size_reading_waits_for_the_check_and_is_a_row_of_the_analysis():
    rows = _checked((0.0, 0.0), (0.0, 0.0))
    rows[1] = {**rows[1], "estimate": "", "decision": "pending"}
    assert thesis_ac.step_size_reading(rows) == "pending"
    out = thesis_ac.analysis([])
    assert [r["decision"] for r in out if r["contrast"] == thesis_ac.STEP_SIZE_ROW] == ["pending"]


def _p(x: float) -> str:
    """A p-value as the page writes it: 1.0 from 0.9995, two significant digits, below 0.001 as a·10⁻ⁿ."""
    if x >= 0.9995:
        return "1.0"
    if x >= 0.001:
        return f"{x:.2g}"
    m, e = f"{x:.1e}".split("e")
    return f"{m}·10" + str(int(e)).translate(str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹"))


def _recomputed(rows: list[dict], fine: float) -> tuple[dict, dict, dict]:
    """Each of T1-T7 at ``fine`` on both endpoints by hand (:func:`_welch_contrast`) from rows.csv,
    with the Holm-adjusted p and TOST p over the 14, keyed by (endpoint, contrast)."""
    keys = [(e, t) for e in _MARGINS for t in _WRITTEN]
    res = {(e, t): _welch_contrast([_runs(rows, e, arm, fine if dt == 0.0025 else dt) for arm, dt, _ in _WRITTEN[t]],
                                   [w for *_, w in _WRITTEN[t]], _MARGINS[e]) for e, t in keys}
    return (res, dict(zip(keys, _holm([res[k][3] for k in keys]))),
            dict(zip(keys, _holm([res[k][4] for k in keys]))))


def _assert_page_table(doc: str, rows: list[dict], fine: float, suffix: str) -> None:
    """The page's table of the family at ``fine`` (rows labelled "T1 (AUC{suffix})"...): every cell
    recomputed by hand; the bootstrap interval and the decision are analysis.csv's (checked elsewhere)."""
    from tests.doc_numbers import n, table_row

    family = "primary" if fine == 0.0025 else "secondary"
    fam = {(r["endpoint"], r["contrast"]): r for r in _published("analysis.csv") if r["family"] == family}
    res, holm, tost = _recomputed(rows, fine)
    for (e, t), (d, lo, hi, p, tp) in res.items():
        cells = table_row(doc, f"{t} ({'AUC' if e == 'auc_reward_per_s' else 'det.'}{suffix})")
        boot = fam[e, t]
        assert cells[2:8] == [f"{n(d, True)} [{n(lo)}, {n(hi)}]",
                              f"[{n(float(boot['boot_lo']))}, {n(float(boot['boot_hi']))}]",
                              _p(p), _p(holm[e, t]), f"{_p(tp)} ({_p(tost[e, t])})", boot["decision"]]


@pytest.mark.record
def test_the_pages_secondary_table_and_cells_are_the_published_rows():
    """The page's table of the secondary family (5 ms) and its 5 ms cells' means and SDs, from
    rows.csv by hand."""
    from tests.doc_numbers import n

    rows = _published("rows.csv")
    if len([r for r in rows if r["cell"] == "grid/dt0.005" and r["det_reward_per_s"]]) < 24:
        pytest.skip("the 5 ms cell is not published in full")
    doc = _doc()
    _assert_page_table(doc, rows, 0.005, ", 5 ms")
    fine = [r for r in rows if r["cell"] == "grid/dt0.005"]
    assert {(r["steps"], r["budget"], r["diverged"]) for r in fine} == {("626000", "625000", "False")}
    speeds = [float(r["det_forward_speed"]) for r in fine]
    assert min(speeds) >= 1.0
    res, holms, _ = _recomputed(rows, 0.005)
    d, lo, hi, *_ = res["auc_reward_per_s", "T1"]
    holm = holms["auc_reward_per_s", "T1"]
    assert_numbers((REPO / "README.md").read_text(), [n(d, True), n(lo), n(hi), f"{holm:.3f}"], label="At 5 ms")
    assert_numbers(doc, [f"{min(speeds):.2f}", f"{max(speeds):.2f}"], label="every run walks (deterministic forward speed")
    for arm in (_S, _A, _B):
        for key in _MARGINS:
            v = _runs(rows, key, arm, 0.005)
            assert_numbers(doc, [n(v.mean()), n(v.std(ddof=1))], window=20)


@pytest.mark.record
def test_the_pages_primary_table_and_the_readme_are_the_published_rows():
    """The Results table of the page, every row recomputed from rows.csv by hand (Welch, TOST,
    Holm over the 14; the bootstrap interval is analysis.csv's, checked against scipy elsewhere),
    the cells' means and SDs, and the README's numbers."""
    from tests.doc_numbers import n

    rows = _published("rows.csv")
    if len([r for r in rows if r["cell"] == "grid/dt0.0025" and r["det_reward_per_s"]]) < 24:
        pytest.skip("the 2.5 ms cell is not published in full")
    fam = {(r["endpoint"], r["contrast"]): r for r in _published("analysis.csv") if r["family"] == "primary"}

    res, holm, _ = _recomputed(rows, 0.0025)
    doc, readme = _doc(), (REPO / "README.md").read_text()
    _assert_page_table(doc, rows, 0.0025, "")
    assert fam["", "the thesis"]["decision"] == "fails"
    for arm in (_S, _A, _B):
        for key in _MARGINS:
            for dt in (0.02, 0.0025):
                v = _runs(rows, key, arm, dt)
                assert_numbers(doc, [n(v.mean()), n(v.std(ddof=1))], window=20)
    d, lo, hi, *_ = res["auc_reward_per_s", "T1"]
    assert_numbers(readme, [n(d, True), n(lo), n(hi), _p(holm["auc_reward_per_s", "T1"])], label="on the AUC it gains")
    d, lo, hi, *_ = res["det_reward_per_s", "T1"]
    assert_numbers(readme, [n(d, True), n(lo), n(hi)], label="deterministic endpoint is not detected")
    for t in ("T4", "T5"):
        d, lo, hi, *_ = res["auc_reward_per_s", t]
        assert_numbers(readme, [n(-d), n(-hi), n(-lo)], label="falls by", window=120)
    speeds = [float(r["det_forward_speed"]) for r in rows if r["cell"] == "grid/dt0.0025"]
    assert_numbers(doc, [f"{min(speeds):.2f}", f"{max(speeds):.2f}"], label="Every run at 2.5 ms walks")
    walking = sum(float(r["det_forward_speed"]) >= 1.0 for r in rows if r["cell"] in ("grid/dt0.02", "grid/dt0.0025"))
    assert_numbers(readme, [str(walking), "48"], label="10⁵ simulated seconds per run")


def _mean_curve(arm: str, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The 8 runs' mean exploring reward per second by chunk, read from metrics.jsonl by hand: the
    reward per step is scaled by δ / 20 ms, so a chunk's reward per second is its mean over 20 ms;
    its time is the steps over δ."""
    points = REPO / "results" / "thesis_ac" / "grid" / f"dt{dt:g}" / "points"
    runs = [[json.loads(line) for line in (points / f"{arm}_s{s}" / "metrics.jsonl").read_text().splitlines()]
            for s in range(8)]
    return (np.array([m["step"] * dt for m in runs[0]]),
            np.mean([[m["avg_reward"] / 0.02 for m in run] for run in runs], axis=0))


@pytest.mark.record
def test_the_pages_learning_curve_description_is_the_published_metrics():
    """The minima of the mean curves the page describes, and T1's AUC split at 2000 s."""
    from tests.doc_numbers import n

    if len([r for r in _published("rows.csv") if r["cell"] == "grid/dt0.005" and r["det_reward_per_s"]]) < 24:
        pytest.skip("the 5 ms cell is not published in full")
    doc = _doc()
    for dt in (0.02, 0.005, 0.0025):
        t, y = _mean_curve(_S, dt)
        assert_numbers(doc, [n(y.min()), f"{t[y.argmin()]:g}"], label="the minimum of its 8 runs' mean curve", window=400)
    lows = []
    for arm in (_A, _B):
        for dt in (0.02, 0.005, 0.0025):
            t, y = _mean_curve(arm, dt)
            assert t[y.argmin()] <= 30.0
            lows.append(y.min())
    assert_numbers(doc, [n(min(lows)), n(max(lows))], label="lowest in their first 30 s")
    t, fine = _mean_curve(_S, 0.0025)
    _, coarse = _mean_curve(_S, 0.02)
    d = fine - coarse
    assert t.size == 313 and t[-1] == pytest.approx(3130.0)
    early = t <= 2000.0
    assert_numbers(doc, [n(d.mean(), True), n(d[early].sum() / d.size, True), n(d[~early].sum() / d.size, True)],
                   label="Of T1's")


#: the check's cells as the page labels them: the factor of both step sizes in the point's name
_CHECK = (("3", "×3"), ("0.333", "×⅓"))


@pytest.mark.record
def test_the_pages_step_size_check_and_the_readme_are_the_published_rows():
    """The page's table of the step-size check, every row by hand from rows.csv (each scaled
    stationary cell at 2.5 ms minus the grid's stationary(2.5), Welch), whether each estimate lies
    above the endpoint's margin and the reading that follows in the page and the README, and the
    scaled cells' means, SDs, forward speeds and actor's norms (metrics.jsonl's last chunk)."""
    from tests.doc_numbers import n, table_row

    rows = _published("rows.csv")
    scaled = {f: _check_rows(rows, f) for f, _ in _CHECK}
    if any(len(v) < 4 or not all(r["det_reward_per_s"] for r in v) for v in scaled.values()):
        pytest.skip("the step-size check is not published in full")
    doc, readme = _doc(), (REPO / "README.md").read_text()
    above = False
    for f, label in _CHECK:
        for key, margin in _MARGINS.items():
            x = np.array([float(r[key]) for r in scaled[f]])
            d, lo, hi, p, _ = _welch_contrast([x, _runs(rows, key, _S, 0.0025)], [1, -1], margin)
            cells = table_row(doc, f"{label} ({'AUC' if key == 'auc_reward_per_s' else 'det.'})")
            assert cells[2:5] == [f"{n(d, True)} [{n(lo)}, {n(hi)}]", _p(p), "yes" if d > margin else "no"]
            assert_numbers(doc, [n(x.mean()), n(x.std(ddof=1))], label=f"{label}:", window=200)
            above |= d > margin
        speeds = [float(r["det_forward_speed"]) for r in scaled[f]]
        norms = [json.loads((REPO / "results/thesis_ac/check/dt0.0025/points" / r["point"] / "metrics.jsonl")
                            .read_text().splitlines()[-1])["theta_norm"] for r in scaled[f]]
        assert_numbers(doc, [f"{min(speeds):.2f}", f"{max(speeds):.2f}", n(min(norms)), n(max(norms))],
                       label=f"{label}:", window=400)
    reading = "conditional" if above else "unconditional"
    assert [r["decision"] for r in _published("analysis.csv") if r["contrast"] == thesis_ac.STEP_SIZE_ROW] == [reading]
    assert f"reading: {reading}" in doc.replace("*", "") and f"reading: {reading}" in readme.replace("*", "")
