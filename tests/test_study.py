"""The finer-delta study (nmrl/experiments/study.py) and the gradient-variance statistics (nmrl/experiments/gradvar.py)."""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import numpy as np
import pytest

from nmrl import options
from nmrl.runs import driver as run
from nmrl.experiments import gradvar, study
from nmrl.learners.ac_config import TrainConfig
from nmrl.experiments.timescale import DELTA_0, TimescaleSpec

REPO = pathlib.Path(__file__).resolve().parents[1]

# ------------------------------------------------------------------ gradvar.summarize vs numpy / MC


def _batch_sums(g: np.ndarray, batches: int):
    parts = np.array_split(g, batches)
    return (np.array([len(p) for p in parts]), np.stack([p.sum(0) for p in parts]),
            np.array([float(np.sum(p * p)) for p in parts]))


def test_summarize_equals_numpy_sample_statistics():
    rng = np.random.default_rng(0)
    mu = rng.normal(size=7)
    g = mu + rng.normal(size=(5000, 7)) * np.linspace(0.5, 3.0, 7)
    n, s, q = _batch_sums(g, 10)
    st = gradvar.summarize(n, s, q, period_s=0.2)
    trcov = float(np.sum(np.var(g, axis=0, ddof=1)))
    assert math.isclose(st["trcov"], trcov, rel_tol=1e-9)
    assert math.isclose(st["mean_sq"], float(np.sum(g.mean(0) ** 2)) - trcov / len(g), rel_tol=1e-9)
    assert math.isclose(st["snr_per_s"], st["mean_sq"] / (st["trcov"] * 0.2), rel_tol=1e-12)
    assert st["periods"] == 5000 and st["batches"] == 10 and st["trcov_ci"] > 0


def test_summarize_mean_sq_is_unbiased_monte_carlo():
    """E[mean_sq] = |E g|^2 even when the noise dwarfs the mean (small samples)."""
    rng = np.random.default_rng(1)
    mu = np.array([0.3, -0.2, 0.1])  # |mu|^2 = 0.14
    est = []
    for _ in range(4000):
        g = mu + 2.0 * rng.normal(size=(20, 3))
        n, s, q = _batch_sums(g, 2)
        est.append(gradvar.summarize(n, s, q, period_s=1.0)["mean_sq"])
    est = np.array(est)
    se = est.std(ddof=1) / math.sqrt(len(est))
    assert abs(est.mean() - 0.14) < 4 * se, (est.mean(), se)
    naive = np.mean(est + 12.0 / 40)  # |g_bar|^2 would be biased by tr Cov / n = 12 / 40
    assert abs(naive - 0.14) > 10 * se


def test_summarize_rejects_bad_sums():
    with pytest.raises(ValueError, match="at least 2 periods"):
        gradvar.summarize(np.array([1, 5]), np.zeros((2, 3)), np.zeros(2), 0.2)
    with pytest.raises(ValueError, match="inconsistent"):
        gradvar.summarize(np.array([3, 5]), np.zeros((3, 3)), np.zeros(2), 0.2)


# ------------------------------------------------------------------ spec and rules


def test_arm_configs_follow_the_per_second_rules():
    spec = TimescaleSpec()
    for dt in spec.dts:
        k = dt / DELTA_0
        for p in spec.periods:
            c = spec.arm_config(dt, p)
            assert c.environment.control_dt == dt and c.reward_scale == pytest.approx(k)
            assert c.l == (1 if p is None else round(p / dt))
            assert c.budget.chunk_steps * dt == pytest.approx(spec.chunk_seconds)
            assert c.gamma ** (1 / dt) == pytest.approx(0.995 ** 50)
        names, cfgs = spec.grid_points(dt)
        assert len(names) == len(set(names)) == len(spec.periods) * 9
        assert all(c.budget.steps * dt == pytest.approx(spec.grid_seconds) for c in cfgs)


@pytest.mark.parametrize("spec", [TimescaleSpec(), TimescaleSpec(physics="c", num_envs=8)], ids=["default", "c"])
def test_each_cell_is_one_points_sweep_of_the_specs_configs(spec):
    """A grid cell (and a final cell at any chosen pairs) lists the spec's points as ``nmrl sweep
    --points`` takes them: one program, each point's config the spec's, the budget the cell's."""
    from nmrl.experiments import sweep, timescale_cells
    from nmrl.experiments.timescale import arm_name

    for cell, dt in zip(timescale_cells.grid_cells(spec), spec.dts):
        names, cfgs = spec.grid_points(dt)
        chosen = {arm_name(p): (spec.beta_theta_grid[-1], spec.beta_v_grid[0]) for p in spec.periods}
        fnames, fcfgs = spec.final_points(dt, chosen)
        final = timescale_cells.points_cell("final", dt, fnames, fcfgs)
        assert (cell.name, final.name) == (f"grid/dt{dt:g}", f"final/dt{dt:g}")
        for c, want_names, want in ((cell, names, cfgs), (final, fnames, fcfgs)):
            steps = c.steps
            sw = sweep.SweepSpec(ls=(None,), seeds=1, base=options.build(TrainConfig, steps=steps), field=None, overrides=c.points)
            sw.validate()
            assert sw.names() == want_names and sw.point_configs() == want


@pytest.mark.parametrize("kw,needle", [
    (dict(dts=()), "dts"),
    (dict(dts=(0.02, 0.02)), "dts"),
    (dict(dts=(0.03,), chunk_seconds=0.6, grid_seconds=1.2, final_seconds=1.2),
     "not a positive integer"),  # 0.1 s / 0.03 s
    (dict(periods=(None, -0.1)), "periods"),
    (dict(beta_theta_grid=(1e-5, -1.0)), "beta_theta_grid"),
    (dict(seeds=0), "seeds=0"),
    (dict(grid_seconds=12.0), "multiple of chunk_seconds"),
    (dict(gradvar_batches=1), "gradvar_batches"),
])
def test_bad_spec(kw, needle):
    with pytest.raises(ValueError, match=needle):
        TimescaleSpec(**kw).validate()


def test_cli_bad_value_writes_nothing(tmp_path, capsys):
    from nmrl import cli

    assert cli.main(["study", "--out", str(tmp_path / "s"), "--seeds", "0"]) == 2
    assert "seeds=0 is invalid" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_cli_bad_period(capsys):
    with pytest.raises(SystemExit):
        study.main(["--out", "/nonexistent/x", "--periods", "fast"])
    assert "period 'fast' is invalid" in capsys.readouterr().err


# ------------------------------------------------------------------ a whole (tiny) study

TINY = TimescaleSpec(dts=(0.02,), periods=(None, 0.04), beta_theta_grid=(1e-5, 3e-5), beta_v_grid=(5e-4,),
                       grid_seconds=2.0, final_seconds=2.0, chunk_seconds=1.0, seeds=2, num_envs=4,
                       checkpoint_every=1, gradvar_envs=4, gradvar_batches=2,
                       base=TrainConfig(hidden_actor=8, hidden_critic=8))


@pytest.fixture(scope="module")
def tiny_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    res = study.run_study(TINY, out, progress=False)
    return out, res


@pytest.mark.slow  # the whole tiny study (~2.5 min cold)
def test_grid_choice_follows_the_rule(tiny_study):
    out, res = tiny_study
    assert len(res["grid"]) == 4
    for arm in ("stationary", "p0.04s"):
        rows = [r for r in res["grid"] if r["arm"] == arm]
        scores = {}
        for r in rows:  # the rule, recomputed from the raw metrics: mean over the second half
            name = f"{arm}_bt{float(r['beta_theta']):.1e}_bv{float(r['beta_v']):.1e}"
            m = run.read_metrics(out / "grid" / "dt0.02" / "points" / name)
            assert [x["step"] for x in m] == [50, 100]
            scores[name] = np.mean([x["avg_reward"] for x in m[1:]])
            assert float(r["score"]) == pytest.approx(scores[name])
        chosen = [r for r in rows if r["chosen"] is True]  # study tables read back typed
        assert len(chosen) == 1
        assert float(chosen[0]["score"]) == pytest.approx(max(scores.values()))
        finals = [r for r in res["final"] if r["arm"] == arm]
        assert sorted(int(r["seed"]) for r in finals) == [0, 1]
        for r in finals:  # every seed runs at the chosen step sizes, the same simulated time
            assert (r["beta_theta"], r["beta_v"]) == (chosen[0]["beta_theta"], chosen[0]["beta_v"])
            assert float(r["seconds"]) == pytest.approx(2.0)
            # from the point's own files: the received reward (reward_scale * r_t, config.json) summed
            # over one second (1 / control_dt steps), the mean over the last tenth of metrics.jsonl
            d = out / "final" / "dt0.02" / "points" / f"{arm}_s{r['seed']}"
            cfg = json.loads((d / "config.json").read_text())
            raw = [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines()]
            assert len(raw) == 2  # 2 chunks: the last tenth is the last chunk
            want = raw[-1]["avg_reward"] * cfg["reward_scale"] / cfg["control_dt"]
            assert float(r["reward_per_s"]) == pytest.approx(want, rel=1e-9)
            assert r["collapsed"] is (raw[-1]["theta_norm"] > 1.5 * raw[0]["theta_norm"])


def _write_rows(d, rows):
    d.mkdir(parents=True)
    (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def _row(step, avg, theta=10.0, speed=0.0, diverged=False):
    return {"step": step, "trials": step // 5, "avg_reward": avg, "forward_speed": speed,
            "theta_norm": theta, "v_norm": 1.0, "diverged": diverged}


def test_rows_from_hand_written_metrics(tmp_path):
    """grid.csv and final.csv from metrics.jsonl rows written here, at delta = 0.01 s (where the
    received reward is 0.5 r_t and a second has 100 steps), against values computed by hand."""
    spec = TimescaleSpec(dts=(0.01,), periods=(None, 0.04), beta_theta_grid=(1e-5, 3e-5), beta_v_grid=(5e-4,),
                           chunk_seconds=0.1, grid_seconds=0.4, final_seconds=2.0, seeds=2)
    grid = tmp_path / "grid" / "dt0.01" / "points"
    # stationary: the second half decides (1e-5: 1.5 although its whole mean is lower than 3e-5's)
    _write_rows(grid / "stationary_bt1.0e-05_bv5.0e-04", [_row(10 * i, a) for i, a in
                                                          enumerate([-3.0, -3.0, 1.5, 1.5], 1)])
    _write_rows(grid / "stationary_bt3.0e-05_bv5.0e-04", [_row(10 * i, a) for i, a in
                                                          enumerate([3.0, 3.0, 1.0, 1.0], 1)])
    # 0.04 s periods: 3e-5 diverged (never chosen, however high its rewards)
    _write_rows(grid / "p0.04s_bt1.0e-05_bv5.0e-04", [_row(10 * i, a) for i, a in
                                                      enumerate([0.0, 0.0, 0.5, 0.5], 1)])
    _write_rows(grid / "p0.04s_bt3.0e-05_bv5.0e-04", [_row(10, 9.0), _row(20, 9.0, diverged=True)])
    final = tmp_path / "final" / "dt0.01" / "points"
    # 20 chunks of 10 steps: the last tenth is the last 2 chunks
    avg = [-1.0] * 18 + [0.3, 0.5]  # last tenth 0.4 -> 0.4 * 0.5 * 100 = 20 per second
    speed = [0.0] * 18 + [1.0, 2.0]  # -> 1.5 m/s
    for arm, seed, first, second, last in (("stationary", 0, 10.0, 5.0, 14.9), ("stationary", 1, 10.0, 20.0, 15.1),
                                           ("p0.04s", 0, 4.0, 9.0, 5.0), ("p0.04s", 1, 4.0, 4.0, 6.5)):
        thetas = [first, second] + [5.0] * 17 + [last]
        _write_rows(final / f"{arm}_s{seed}", [_row(10 * i, a + seed, th, v) for i, (a, th, v) in
                                               enumerate(zip(avg, thetas, speed), 1)])
    res = study.run_study(spec, tmp_path, phases=(), progress=False)
    got = {(r["arm"], float(r["beta_theta"])): r for r in res["grid"]}
    assert {k: float(r["score"]) for k, r in got.items()} == {
        ("stationary", 1e-5): 1.5, ("stationary", 3e-5): 1.0, ("p0.04s", 1e-5): 0.5, ("p0.04s", 3e-5): -math.inf}
    assert {k for k, r in got.items() if r["chosen"] is True} == {("stationary", 1e-5), ("p0.04s", 1e-5)}
    assert got[("p0.04s", 3e-5)]["diverged"] is True
    fin = {(r["arm"], int(r["seed"])): r for r in res["final"]}
    assert len(fin) == 4
    for (arm, seed), r in fin.items():
        assert float(r["beta_theta"]) == 1e-5 and float(r["seconds"]) == pytest.approx(2.0)
        assert int(r["steps"]) == 200 and r["diverged"] is False
        assert float(r["avg_reward"]) == pytest.approx(0.4 + seed)
        assert float(r["reward_per_s"]) == pytest.approx([20.0, 70.0][seed])  # (0.4 + seed) * 0.5 * 100
        assert float(r["forward_speed"]) == pytest.approx(1.5)
    # collapsed: the last norm above 1.5 x the norm after the first chunk (10 -> 15, 4 -> 6; the
    # second chunk's norms would give the opposite answers)
    assert {k: r["collapsed"] for k, r in fin.items()} == {
        ("stationary", 0): False, ("stationary", 1): True, ("p0.04s", 0): False, ("p0.04s", 1): True}


@pytest.mark.slow  # the whole tiny study (~2.5 min cold)
def test_gradvar_rows_and_figures(tiny_study, tmp_path, saved_figures):
    out, res = tiny_study
    rows = res["gradvar"]
    pols = sorted({r["policy"] for r in rows})
    assert len(pols) == 3 and pols[0] == "initial"
    assert pols[1].startswith("trained_p0.04s_s") and pols[2].startswith("trained_stationary_s")
    for p in pols[1:]:  # the seed with the highest final reward of that arm
        arm, seed = p[len("trained_"):].rsplit("_s", 1)
        rows_arm = [r for r in res["final"] if r["arm"] == arm]
        assert int(seed) == int(max(rows_arm, key=lambda r: float(r["avg_reward"]))["seed"])
    for r in rows:
        assert float(r["trcov"]) > 0 and int(r["periods"]) >= 2
        # 4 envs x 2 batches x 1 s, one period per step (stationary) or per 2 steps (0.04 s), minus stops
        per = 0.02 if r["arm"] == "stationary" else 0.04
        assert 0.8 * 8 / per <= int(r["periods"]) <= 8 / per
    assert (out / "timescale.png").is_file() and (out / "grid.png").is_file()
    _check_timescale_figures(out, res, tmp_path, saved_figures)


def _per_second(point, rows):
    """Each chunk's received reward per simulated second, from the point's config.json."""
    cfg = json.loads((point / "config.json").read_text())
    return np.array([r["avg_reward"] for r in rows]) * cfg["reward_scale"] / cfg["control_dt"]


def _check_timescale_figures(out, res, tmp_path, saved):
    """What the study's figures draw: the final rows' mean reward per second with its 95% t-interval,
    the learning curves and the grid's scores per second, against the files read here."""
    from matplotlib.container import ErrorbarContainer

    from nmrl.analysis import plots

    curves: dict = {}  # each final point's metrics rows, read here from its metrics.jsonl
    for r in res["final"]:
        d = out / "final" / f"dt{float(r['dt'])}" / "points" / f"{r['arm']}_s{r['seed']}"
        curves.setdefault((r["arm"], float(r["dt"])), []).append(
            [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines()])
    plots.timescale(out, res["grid"], res["final"], res["gradvar"], curves, path=tmp_path / "timescale.png")
    (fig,) = [f for p, f in saved if p.name.startswith("timescale")]
    (gfig,) = [f for p, f in saved if p.name.startswith("grid")]
    labels = {"stationary": "stationary (l = 1)", "p0.04s": "nm-period 0.04 s"}
    ax = fig.axes[0]
    bars = {c.get_label(): c for c in ax.containers if isinstance(c, ErrorbarContainer)}
    assert set(bars) == set(labels.values())
    curves = {ln.get_label(): ln for ln in fig.axes[3].lines}  # the learning curves at delta = 0.02 s
    for arm, label in labels.items():
        v = [float(r["reward_per_s"]) for r in res["final"] if r["arm"] == arm]
        assert len(v) == 2
        x, y = (np.asarray(a, float) for a in bars[label].lines[0].get_data())
        ((_, lo), (_, hi)), = bars[label].lines[2][0].get_segments()
        np.testing.assert_allclose(x, [0.02])
        np.testing.assert_allclose(y, [np.mean(v)])
        np.testing.assert_allclose(hi - y[0], 12.706204736174707 * abs(v[0] - v[1]) / 2)  # t(0.975, 1) s / sqrt 2
        points = [out / "final" / "dt0.02" / "points" / f"{arm}_s{s}" for s in (0, 1)]
        per_s = [_per_second(p, [json.loads(x) for x in (p / "metrics.jsonl").read_text().splitlines()]) for p in points]
        mean = np.mean(per_s, axis=0)
        np.testing.assert_allclose(curves[label].get_xdata(), [1.0, 2.0])  # 50 and 100 steps of 0.02 s
        np.testing.assert_allclose(curves[label].get_ydata(), [mean[0], (mean[0] + mean[1]) / 2], rtol=1e-6)
        gax = [a for a in gfig.axes if a.get_title() == f"δ=0.02 s, {label}"][0]
        z = gax.images[0].get_array()
        for r in (r for r in res["grid"] if r["arm"] == arm):
            i, j = [1e-5, 3e-5].index(float(r["beta_theta"])), 0
            name = f"{arm}_bt{float(r['beta_theta']):.1e}_bv{float(r['beta_v']):.1e}"
            p = out / "grid" / "dt0.02" / "points" / name
            m = [json.loads(x) for x in (p / "metrics.jsonl").read_text().splitlines()]
            assert z[i, j] == pytest.approx(float(np.mean(_per_second(p, m[len(m) // 2:]))), rel=1e-6)
            if r["chosen"]:
                (rect,) = gax.patches
                assert rect.get_xy() == (j - 0.5, i - 0.5) and rect.get_edgecolor()[:3] == (1.0, 0.0, 0.0)


@pytest.mark.slow  # the whole tiny study (~2.5 min cold)
def test_rerun_is_a_no_op_and_other_settings_are_refused(tiny_study):
    out, res = tiny_study
    before = (out / "final.csv").read_text()
    again = study.run_study(TINY, out, progress=False, phases=("grid", "final", "gradvar"))
    assert again["final"] == res["final"] and (out / "final.csv").read_text() == before
    with pytest.raises(study.StudyError, match="seeds"):
        study.run_study(dataclasses.replace(TINY, seeds=3), out, progress=False)
    with pytest.raises(study.StudyError, match="final_seconds"):  # a shorter final budget
        study.run_study(dataclasses.replace(TINY, final_seconds=1.0), out, progress=False)
    with pytest.raises(study.StudyError, match="already measured"):  # gradvar.csv exists
        study.run_study(dataclasses.replace(TINY, gradvar_envs=8), out, progress=False)
    assert json.loads((out / "study.json").read_text())["seeds"] == 2


@pytest.mark.slow  # the whole tiny study (~2.5 min cold)
def test_longer_final_budget_extends_the_final_runs(tiny_study, tmp_path):
    import shutil

    src, res = tiny_study
    out = tmp_path / "ext"
    shutil.copytree(src, out)
    longer = dataclasses.replace(TINY, final_seconds=3.0)
    ext = study.run_study(longer, out, progress=False, phases=("grid", "final"))
    assert ext["grid"] == res["grid"]
    assert {float(r["seconds"]) for r in ext["final"]} == {3.0}
    for r in ext["final"]:
        m = run.read_metrics(out / "final" / "dt0.02" / "points" / f"{r['arm']}_s{r['seed']}")
        assert [x["step"] for x in m] == [50, 100, 150]
        old = run.read_metrics(src / "final" / "dt0.02" / "points" / f"{r['arm']}_s{r['seed']}")
        assert [{k: v for k, v in x.items() if k not in ("wall_s", "steps_per_s")} for x in m[:2]] == \
            [{k: v for k, v in x.items() if k not in ("wall_s", "steps_per_s")} for x in old]
    assert (out / "gradvar_final2s.csv").exists() and not (out / "gradvar.csv").exists()
    assert json.loads((out / "study.json").read_text())["final_seconds"] == 3.0


@pytest.mark.slow  # the whole tiny study (~2.5 min cold)
def test_beta_theta_cap_reuses_the_grid(tiny_study, tmp_path):
    import os
    import shutil

    src, res = tiny_study
    out = tmp_path / "cap"
    out.mkdir()
    shutil.copytree(src / "grid", out / "grid")
    stamps = {p: os.stat(p).st_mtime_ns for p in (out / "grid").rglob("metrics.jsonl")}
    capped = dataclasses.replace(TINY, beta_theta_cap=1e-5)
    got = study.run_study(capped, out, progress=False, phases=("grid", "final"))
    assert {p: os.stat(p).st_mtime_ns for p in (out / "grid").rglob("metrics.jsonl")} == stamps  # not rerun
    for arm in ("stationary", "p0.04s"):
        rows = [r for r in got["grid"] if r["arm"] == arm]
        chosen = [r for r in rows if r["chosen"] is True]  # study tables read back typed
        assert len(chosen) == 1 and float(chosen[0]["beta_theta"]) == 1e-5  # the only pair under the cap
        assert {float(r["score"]) for r in rows} == {float(r["score"]) for r in res["grid"] if r["arm"] == arm}
    assert {float(r["beta_theta"]) for r in got["final"]} == {1e-5}
    with pytest.raises(ValueError, match="beta_theta_cap"):
        dataclasses.replace(TINY, beta_theta_cap=1e-7).validate()


@pytest.mark.parametrize("name", ["timescale", "timescale_cap", "timescale_cap300"])
def test_a_published_study_json_loads_as_the_spec_and_keeps_every_stored_value(name):
    """Every published study.json (of older formats too: fewer fields, the defaults then) is a valid
    spec whose JSON holds every stored value unchanged, and reads back to the same spec."""
    d = json.loads((REPO / "results" / name / "study.json").read_text())
    spec = TimescaleSpec.from_json(d)
    spec.validate()
    again = spec.to_json()
    assert {k: again[k] for k in d if k != "base"} == {k: v for k, v in d.items() if k != "base"}
    assert {k: again["base"][k] for k in d["base"]} == d["base"]
    assert TimescaleSpec.from_json(again) == spec and spec.base == options.build(TrainConfig, **d["base"])
