"""The sweep (nmrl/experiments/sweep.py, Sec. V-D / Fig. 3): one vmapped program equals separate runs."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest

from nmrl import cli
from nmrl.runs import checkpoint, driver as run
from nmrl.experiments import sweep
from nmrl.paper.learner import TrainConfig, make_train

# Tiny networks, 8 environments, 2 chunks of 25 steps: 400 periods per point at l = 1.
BASE = TrainConfig(num_envs=8, chunk_steps=25, steps=50, hidden_actor=8, hidden_critic=8,
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


def test_results_file_and_figure(swept):
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
    assert (out / "fig3.png").stat().st_size > 10_000


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
            run.train(dataclasses.replace(BASE, l=l, seed=seed), d, progress=False)
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


def test_resume_keeps_a_diverged_point_frozen(swept, tmp_path):
    """A diverged point has no checkpoint after its last good step: the others must not go back."""
    import shutil

    out, _ = swept
    part = tmp_path / "frozen"
    shutil.copytree(out, part)
    bad = sweep.point_dir(part, 3, 1)
    shutil.rmtree(bad / "checkpoints" / "50")
    rows = run.read_metrics(bad)
    run.truncate_metrics(bad, 25)
    run.append_metrics(bad, {**rows[-1], "diverged": True})
    before = run.read_metrics(bad)
    sweep.run_sweep(sweep.SweepSpec(ls=(99,), seeds=1, base=dataclasses.replace(BASE, steps=75)), part,
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
