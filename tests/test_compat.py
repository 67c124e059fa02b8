"""Run directories written by the code before the layered package (commit f021abf) still work.

tests/data/f021abf_train_run and tests/data/f021abf_sweep_run were written by ``nmrl train`` and
``nmrl sweep`` at f021abf and stopped after one chunk (tests/data/make_f021abf_runs.py); the same
code, run on without interruption to step 10, wrote tests/data/expected_*. Resuming them with
today's code must continue every point from its checkpoint and reproduce those metrics (the
learner is unchanged, the restored state is the full training state): counters and flags exactly;
real numbers exactly on the machine that wrote the data, and to float32 rounding elsewhere (XLA's
CPU code differs between processors: on an AMD EPYC the continued chunk's metrics moved by up to
2*10^-7 absolute, 1*10^-5 relative on a near-zero speed). A continuation from anything but the
saved state changes them by far more: continuing the two sweep points from their compact states
(fresh traces and trials) moved the float metrics by a median 0.02-0.03 and at most 0.56 and 0.89.
"""

from __future__ import annotations

import json
import pathlib
import shutil

import jax
import numpy as np

from nmrl import cli
from nmrl.experiments import sweep
from nmrl.learners.ac_train import make_train
from nmrl.runs import checkpoint, store

DATA = pathlib.Path(__file__).resolve().parent / "data"
#: metrics that depend on the machine's speed, not on the computation
TIMING = {"wall_s", "steps_per_s"}
#: metrics f021abf's code does not write (global norms of the summed pseudo-gradients and updates,
#: the chunk's reward per ended trial)
ADDED = {f"{k}_{p}_{s}" for k in ("gnorm", "unorm") for p in ("theta", "v") for s in ("mean", "max")} | {
    "return_per_trial"}


#: float32 rounding of another processor's XLA code (see the module docstring)
RTOL = ATOL = 1e-5


def _same(g, w) -> bool:
    if isinstance(w, float) and isinstance(g, float):
        return bool(np.isclose(g, w, rtol=RTOL, atol=ATOL, equal_nan=True))
    return g == w


def _same_rows(got: list[dict], want: list[dict]) -> None:
    assert [r["step"] for r in got] == [r["step"] for r in want]
    for g, w in zip(got, want):
        assert set(g) - ADDED == set(w), set(g) ^ set(w)
        diff = {k: (g[k], w[k]) for k in w if k not in TIMING and not _same(g[k], w[k])}
        assert not diff, f"step {w['step']}: {diff}"


def test_f021abf_train_run_restores_and_continues_exactly(tmp_path):
    d = tmp_path / "run"
    shutil.copytree(DATA / "f021abf_train_run", d)
    assert checkpoint.all_steps(d) == [5]
    assert checkpoint.load_metadata(d)["git_commit"].startswith("f021abf")

    # the policy alone (evaluation's path) and the full state agree
    cfg = checkpoint.load_run_config(d)
    full = checkpoint.restore(d, make_train(cfg))
    _, theta, v = checkpoint.restore_policy(d)
    for a, b in zip(jax.tree.leaves((full.theta, full.v)), jax.tree.leaves((theta, v))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    rc = cli.main(["train", "--resume", "--out", str(d), "--steps", "10", "--quiet", "--devices", "1"])
    assert rc == 0
    want = [json.loads(x) for x in (DATA / "expected_train_metrics.jsonl").read_text().splitlines()]
    _same_rows(store.read_metrics(d), want)
    assert checkpoint.all_steps(d) == [5, 10]
    (rec,) = [json.loads(x) for x in (d / store.RESUMES_FILE).read_text().splitlines()]
    assert rec["from_step"] == 5 and rec["budget"] == {"steps": 10, "trials": None}
    assert json.loads((d / store.CONFIG_FILE).read_text())["steps"] == 10


def test_f021abf_sweep_resumes_every_point_exactly(tmp_path):
    d = tmp_path / "sweep"
    shutil.copytree(DATA / "f021abf_sweep_run", d)
    rc = cli.main(["sweep", "--resume", "--l", "1", "--out", str(d), "--steps", "10", "--quiet", "--devices", "1"])
    assert rc == 0
    want = json.loads((DATA / "expected_sweep_metrics.json").read_text())
    assert sorted(want) == ["l1_s0", "l2_s0"]
    for name, rows in want.items():
        p = d / "points" / name
        _same_rows(store.read_metrics(p), rows)
        assert checkpoint.latest_step(p) == 10
        assert checkpoint.load_compact(p)[1]["step"] == 10
    results = sweep.load_results(d)
    assert [(r["l"], r["seed"], r["steps"], r["diverged"]) for r in results] == [(1, 0, 10, False), (2, 0, 10, False)]
    assert json.loads((d / sweep.SPEC_FILE).read_text())["base"]["steps"] == 10
