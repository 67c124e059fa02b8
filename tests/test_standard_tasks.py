"""The HalfCheetah-v5 publication (scripts/publish/publish_standard_tasks.py, nmrl/analysis/standard_tasks.py):
returns per episode from both learners' rows, the Welch interval against scipy, byte-identical
regeneration from the published data."""

from __future__ import annotations

import importlib.util
import json
import pathlib
import shutil

import numpy as np
import pytest
from scipy import stats as sps

from nmrl.runs import store

ROOT = pathlib.Path(__file__).resolve().parents[1]
NUM_ENVS = 64


def _publisher():
    spec = importlib.util.spec_from_file_location("publish_standard_tasks", ROOT / "scripts" / "publish" / "publish_standard_tasks.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _write(dest: pathlib.Path, rng: np.random.Generator, iterations: int = 4) -> dict:
    """Published-layout data of 3 native points and 3 Brax seeds; returns what was written."""
    per_it = 2048  # control steps per environment per iteration
    want = {"native": {}, "brax": {}, "det_native": {}, "det_brax": {}}
    last = iterations * per_it * NUM_ENVS
    for s in range(3):
        p = dest / "native" / "points" / f"s{s}"
        p.mkdir(parents=True)
        store.atomic_write_json(p / "config.json", {"learner": "ppo", "num_envs": NUM_ENVS, "env": "halfcheetah-v5"})
        avg = rng.normal(size=iterations).cumsum()
        (p / "metrics.jsonl").write_text("".join(json.dumps({"step": (i + 1) * per_it, "avg_reward": float(a)}) + "\n"
                                                 for i, a in enumerate(avg)))
        want["native"][s] = avg
        ret = float(rng.normal(3000, 300))
        store.atomic_write_json(p / "eval.json", {"step": iterations * per_it, "deterministic": {"return": {"mean": ret}}})
        want["det_native"][s] = ret
        b = dest / "brax" / f"ppo_s{s}"
        b.mkdir(parents=True)
        tr = rng.normal(size=iterations).cumsum()
        ev = rng.normal(2500, 500, size=iterations)
        rows = [{"step": 0, "train_reward_per_step": None, "eval_return": -300.0}]
        rows += [{"step": (i + 1) * per_it * NUM_ENVS, "train_reward_per_step": float(t), "eval_return": float(e)}
                 for i, (t, e) in enumerate(zip(tr, ev))]
        (b / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
        want["brax"][s] = tr
        want["det_brax"][s] = float(ev[-1])
    want["last"] = last
    return want


def test_the_curves_are_1000_times_the_reward_per_step_and_the_difference_has_welchs_interval(tmp_path):
    want = _write(tmp_path, np.random.default_rng(0))
    out = _publisher().publish(tmp_path)
    lines = (tmp_path / "learning_curves.csv").read_text().splitlines()
    assert lines[0] == "learner,seed,control_steps,return_per_episode"
    got = {}
    for ln in lines[1:]:
        learner, seed, step, ret = ln.split(",")
        got.setdefault((learner, int(seed)), []).append((int(step), float(ret)))
    for s in range(3):
        steps = [(i + 1) * 2048 * NUM_ENVS for i in range(4)]
        assert [x for x, _ in got[("native", s)]] == steps and [x for x, _ in got[("brax", s)]] == steps
        np.testing.assert_allclose([y for _, y in got[("native", s)]], 1000 * want["native"][s], rtol=1e-5)
        np.testing.assert_allclose([y for _, y in got[("brax", s)]], 1000 * want["brax"][s], rtol=1e-5)
    det = out["deterministic"]
    assert det["control_steps"] == want["last"]
    a = np.array([want["det_native"][s] for s in range(3)])
    b = np.array([want["det_brax"][s] for s in range(3)])
    va, vb = a.var(ddof=1) / 3, b.var(ddof=1) / 3
    dof = (va + vb) ** 2 / (va**2 / 2 + vb**2 / 2)
    assert det["native_minus_brax"]["diff"] == pytest.approx(a.mean() - b.mean())
    assert det["native_minus_brax"]["ci95_welch"] == pytest.approx(sps.t.ppf(0.975, dof) * np.sqrt(va + vb))
    t = sps.ttest_ind(a, b, equal_var=False)
    assert t.statistic == pytest.approx((a.mean() - b.mean()) / np.sqrt(va + vb))
    band = {r["control_steps"]: r for r in out["iterations"]}
    for i, step in enumerate(sorted(band)):
        brax_at = [1000 * want["brax"][s][i] for s in range(3)]
        mean = np.mean([1000 * want["native"][s][i] for s in range(3)])
        assert band[step]["within"] == (min(brax_at) <= mean <= max(brax_at))


def test_the_publisher_regenerates_the_same_bytes_from_the_published_data(tmp_path):
    _write(tmp_path / "a", np.random.default_rng(1))
    pub = _publisher()
    pub.publish(tmp_path / "a")
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    pub.publish(tmp_path / "b")
    for name in ("learning_curves.csv", "learning_curves.png", "summary.json", "deterministic.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


@pytest.mark.skipif(not (ROOT / "results" / "standard_tasks" / "summary.json").is_file(), reason="not published")
def test_the_published_folder_regenerates_byte_for_byte(tmp_path):
    src = ROOT / "results" / "standard_tasks"
    shutil.copytree(src, tmp_path / "st")
    _publisher().publish(tmp_path / "st")
    for name in ("learning_curves.csv", "learning_curves.png", "summary.json", "deterministic.csv"):
        if (src / name).is_file():
            assert (tmp_path / "st" / name).read_bytes() == (src / name).read_bytes(), name
