"""The sweep (nmrl/experiments/sweep.py, Sec. V-D / Fig. 3): one vmapped program equals separate runs."""

from __future__ import annotations

import csv
import json
import math
import warnings

import numpy as np
import pytest

from nmrl import cli, options
from nmrl.runs import checkpoint, driver as run, store
from nmrl.experiments import sweep
from nmrl.learners.ac_config import TrainConfig
from nmrl.learners.ac_train import make_train

# Tiny networks, 8 environments, 2 chunks of 25 steps: 400 periods per point at l = 1.
BASE = options.build(TrainConfig, num_envs=8, chunk_steps=25, steps=50, hidden_actor=8, hidden_critic=8,
                   beta_theta=1e-3, beta_v=1e-3)
LS = (1, 3)
SKIP = {"wall_s", "steps_per_s"}


def _rows(d):
    return [{k: v for k, v in r.items() if k not in SKIP} for r in run.read_metrics(d)]


def _theta(d):
    cfg = checkpoint.load_config(d)
    return checkpoint.restore(d, make_train(cfg)).theta


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    spec = sweep.SweepSpec(ls=LS, seeds=2, base=BASE)
    results = sweep.run_sweep(spec, out, progress=False, plot=True)
    return out, results


def test_results_file_and_figure(swept, tmp_path, saved_figures):
    out, results = swept
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0].keys()) == sweep.RESULT_COLUMNS
    assert [(int(r["l"]), int(r["seed"])) for r in rows] == [(1, 0), (1, 1), (3, 0), (3, 1)]
    for r in rows:
        assert int(r["steps"]) == 50
        assert np.isfinite(float(r["avg_reward"]))
        assert r["diverged"] == "False"
        assert checkpoint.latest_step(out / r["checkpoint"]) == 50
    assert (out / "fig3.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    sweep.draw(out, store.read_csv(out / "results.csv"), path=tmp_path / "fig3.png")
    ax, ax2 = _fig3_axes(saved_figures)
    x, y, _, _ = _errorbar(ax)
    np.testing.assert_allclose(x, LS)
    np.testing.assert_allclose(y, [np.mean([float(r["avg_reward"]) for r in rows if int(r["l"]) == l]) for l in LS])
    curves = {ln.get_label(): ln for ln in ax2.lines}
    for l in LS:
        raw = [[json.loads(x) for x in (sweep.point_dir(out, l, s) / "metrics.jsonl").read_text().splitlines()]
               for s in (0, 1)]
        np.testing.assert_allclose(curves[f"l={l}"].get_xdata(), np.mean([[x["trials"] for x in m] for m in raw], 0))
        mean = np.mean([[x["avg_reward"] for x in m] for m in raw], 0)
        np.testing.assert_allclose(curves[f"l={l}"].get_ydata(), _trailing_mean(mean, 5), rtol=1e-12)


def _errorbar(ax):
    """(x, y, lower, upper) of the Axes' one errorbar series."""
    from matplotlib.container import ErrorbarContainer

    (c,) = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
    x, y = c.lines[0].get_xdata(), c.lines[0].get_ydata()
    seg = np.array(c.lines[2][0].get_segments())  # one vertical segment per x: (x, lo), (x, hi)
    np.testing.assert_array_equal(seg[:, 0, 0], x)
    return np.asarray(x, float), np.asarray(y, float), seg[:, 0, 1], seg[:, 1, 1]


def _trailing_mean(y, k):
    return [float(np.mean(y[max(0, i - k + 1):i + 1])) for i in range(len(y))]


def _fig3_axes(saved):
    (fig,) = [f for p, f in saved if p.name.startswith("fig3")]
    ax, ax2 = fig.axes
    return ax, ax2


def test_fig3_draws_the_results_it_is_given(tmp_path, saved_figures):
    """Fig. 3 from rows and learning curves written here: the plotted means, 95% t-intervals, seeds,
    the paper's two values and the curves against numbers computed by hand."""
    from nmrl.analysis import plots

    out = tmp_path / "sw"
    results = []
    finals = {1: [1.0, 2.0, 3.0], 10: [4.0, 6.0, 8.0]}
    for l, vals in finals.items():
        for seed, v in enumerate(vals):
            diverged = (l, seed) == (10, 2)
            results.append({"l": str(l), "seed": str(seed), "trials": str(1000 * l + seed), "steps": "70",
                            "avg_reward": str(v), "forward_speed": "0.5", "diverged": diverged,
                            "checkpoint": ""})
            d = sweep.point_dir(out, l, seed)
            d.mkdir(parents=True)
            rows = [{"step": 10 * i, "trials": 100 * i + seed, "avg_reward": l * 0.1 * i * i + seed}
                    for i in range(1, 8)]
            (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    sweep.draw(out, results)
    ax, ax2 = _fig3_axes(saved_figures)
    x, y, lo, hi = _errorbar(ax)
    # l = 1: mean 2, sd 1; l = 10: the diverged seed (8.0) left out, mean 5, sd sqrt(2)
    t975 = {2: 4.302652729911275, 1: 12.706204736174707}  # Student t quantiles, 2 and 1 d.o.f.
    np.testing.assert_allclose(x, [1, 10])
    np.testing.assert_allclose(y, [2.0, 5.0])
    np.testing.assert_allclose(hi - y, [t975[2] * 1 / math.sqrt(3), t975[1] * math.sqrt(2) / math.sqrt(2)])
    np.testing.assert_allclose(y - lo, hi - y)
    pts = {tuple(o) for c in ax.collections if not c.get_label().startswith("paper")
           for o in np.asarray(c.get_offsets()) if len(o)}
    assert pts >= {(1, 1.0), (1, 2.0), (1, 3.0), (10, 4.0), (10, 6.0)} and (10, 8.0) not in pts
    (paper,) = [c for c in ax.collections if c.get_label().startswith("paper")]
    assert sorted(map(tuple, np.asarray(paper.get_offsets()))) == [(1, 3.28), (10, 4.59)]
    # the points are at different budgets (l = 1 at ~1,000 trials, l = 10 at ~10,000): the title
    # says so and each l is labelled with its median trials
    assert [t.get_text() for t in ax.texts] == ["1 diverged", "1k", "10k"]
    assert ax.get_xlabel() == "period length l" and ax.get_ylabel() == "average reward per step"
    assert "points at 1,000–10,002 trials" in ax.get_title()
    curves = {ln.get_label(): ln for ln in ax2.lines}
    assert set(curves) == {"l=1", "l=10"}
    for l in (1, 10):  # mean over the 3 seeds (the diverged one too), then a trailing mean of 5 chunks
        np.testing.assert_allclose(curves[f"l={l}"].get_xdata(), [100 * i + 1 for i in range(1, 8)])
        mean = [l * 0.1 * i * i + 1 for i in range(1, 8)]
        np.testing.assert_allclose(curves[f"l={l}"].get_ydata(), _trailing_mean(mean, 5))
    assert ax2.get_xlabel() == "trials"


def test_fig3_title_gives_the_common_budget(tmp_path, saved_figures):
    """Points within 5% of each other's trials: one budget in the title, no per-l trial labels."""
    from nmrl.analysis import plots

    results = [{"l": l, "seed": s, "trials": 1000 + 10 * s + l, "avg_reward": float(s), "diverged": False}
               for l in (1, 10) for s in range(3)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no curves yet: no empty legend (matplotlib warns on one)
        plots.fig3(results, {}, tmp_path / "fig3.png")
    ax, ax2 = _fig3_axes(saved_figures)
    assert "after ~1,016 trials" in ax.get_title() and not ax.texts  # median of 1001..1030
    assert not ax2.lines and ax2.get_legend() is None


def _assert_rows_close(a, b, what):
    """Integer and boolean fields exactly, floats to float32 rounding: the sweep's program (lax.map
    over points under lax.cond) and a single run's program are compiled apart, and XLA fuses the
    physics differently in the two (largest relative difference seen: ~2e-7)."""
    assert len(a) == len(b), what
    for ra, rb in zip(a, b):
        assert ra.keys() == rb.keys(), what
        for k in ra:
            if isinstance(ra[k], float):
                np.testing.assert_allclose(ra[k], rb[k], rtol=1e-5, atol=1e-6, err_msg=f"{what} {k}")
            else:
                assert ra[k] == rb[k], (what, k)


def test_every_point_equals_a_separate_train_run(swept, tmp_path):
    out, _ = swept
    for l in LS:
        for seed in (0, 1):
            d = tmp_path / f"l{l}_s{seed}"
            run.train(options.replace(BASE, l=l, seed=seed), d, progress=False)
            p = sweep.point_dir(out, l, seed)
            _assert_rows_close(_rows(d), _rows(p), (l, seed))
            for a, b in zip(jax_leaves(_theta(d)), jax_leaves(_theta(p))):
                np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)


def jax_leaves(t):
    import jax

    return [np.asarray(x) for x in jax.tree.leaves(t)]


def test_resume_equals_uninterrupted(swept, tmp_path):
    out, _ = swept
    spec = sweep.SweepSpec(ls=LS, seeds=2, base=BASE)
    part = tmp_path / "part"
    sweep.run_sweep(spec, part, progress=False, plot=False, max_chunks=1)
    assert all(int(r["steps"]) == 25 for r in sweep.load_results(part))
    with pytest.raises(sweep.SweepError, match="already holds a sweep"):
        sweep.run_sweep(spec, part, progress=False, plot=False)
    sweep.run_sweep(sweep.SweepSpec(ls=(99,), seeds=1, base=TrainConfig()), part, resume=True,
                    progress=False, plot=False)
    assert sweep.load_results(part) == sweep.load_results(out)
    for l in LS:
        for seed in (0, 1):
            assert _rows(sweep.point_dir(part, l, seed)) == _rows(sweep.point_dir(out, l, seed))
    # the finished sweep resumed again: nothing to do, nothing written (no resume records either)
    files = {f: f.read_bytes() for f in part.rglob("*") if f.is_file()}
    assert sweep.run_sweep(sweep.SweepSpec(ls=(99,), seeds=1, base=TrainConfig()), part, resume=True,
                           progress=False, plot=False) == []
    assert {f: f.read_bytes() for f in part.rglob("*") if f.is_file()} == files


def test_resume_keeps_a_diverged_point_frozen(swept, tmp_path):
    """A diverged point has no checkpoint after its last good step: the others must not go back."""
    import shutil

    out, _ = swept
    part = tmp_path / "frozen"
    shutil.copytree(out, part)
    bad = sweep.point_dir(part, 3, 1)
    shutil.rmtree(bad / "checkpoints" / "50")
    rows = run.read_metrics(bad)
    store.truncate_metrics(bad, 25)
    store.append_metrics(bad, {**rows[-1], "diverged": True})
    before = run.read_metrics(bad)
    sweep.run_sweep(sweep.SweepSpec(ls=(99,), seeds=1, base=options.replace(BASE, steps=75)), part,
                    resume=True, progress=False, plot=False)
    for r in sweep.load_results(part):
        l, seed = int(r["l"]), int(r["seed"])
        if (l, seed) == (3, 1):
            assert r["diverged"] is True and r["steps"] == 50  # results.csv reads back typed
            assert run.read_metrics(bad) == before
            assert checkpoint.latest_step(bad) == 25
        else:
            rows = _rows(sweep.point_dir(part, l, seed))
            assert [x["step"] for x in rows] == [25, 50, 75], (l, seed)
            assert rows[:2] == _rows(sweep.point_dir(out, l, seed))


@pytest.mark.parametrize("argv,needle", [
    (["--l"], "expected at least one argument"),
    (["--l", "0", "10"], "l=0"),
    (["--l", "10", "10"], "duplicate"),
    (["--l", "1", "--seeds", "0"], "seeds=0"),
    (["--l", "1", "--alpha", "1.5"], "alpha"),
])
def test_bad_arguments(tmp_path, capsys, argv, needle):
    out = tmp_path / "bad"
    try:
        rc = cli.main(["sweep", *argv, "--out", str(out)])
    except SystemExit as e:  # argparse's own errors
        rc = e.code
    assert rc == 2
    assert needle in capsys.readouterr().err
    assert not out.exists()


def test_a_sweep_of_seeds_alone_gives_each_point_the_base_config_with_its_seed():
    base = options.build(TrainConfig, steps=25, num_envs=3, sigma=0.5)
    spec = sweep.SweepSpec(ls=(None,), seeds=3, seed0=7, base=base, field=None)
    spec.validate()
    cfgs = spec.point_configs()
    assert [c.budget.seed for c in cfgs] == [7, 8, 9]
    for c in cfgs:  # everything but the seed is the base's
        assert options.flat(options.replace(c, seed=0)) == options.flat(options.replace(base, seed=0))
