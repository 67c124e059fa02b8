"""The validation's band test (nmrl/analysis/ppo_validation.py) against a brute-force reading of rows."""

from __future__ import annotations

import json

import numpy as np

from nmrl.analysis import ppo_validation as pv


def _point(d, seed, num_envs, rows):
    p = d / f"s{seed}"
    p.mkdir(parents=True)
    (p / "config.json").write_text(json.dumps({"learner": "ppo", "num_envs": num_envs}))
    (p / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_band_check_against_brute_force(tmp_path):
    rng = np.random.default_rng(0)
    it = 327_680
    peer_runs = {s: [{"step": 0, "train_reward_per_step": None, "eval_avg_reward": -1.0}]
                 + [{"step": k * it, "train_reward_per_step": float(rng.normal(k, 1)), "eval_avg_reward": float(k + s)}
                    for k in range(1, 6 - (s == 2))] for s in range(3)}  # seed 2 stops an iteration early
    for s in range(3):
        _point(tmp_path, s, 64, [{"step": k * it // 64, "avg_reward": float(rng.normal(k, 1))} for k in range(1, 5)])
    native = pv.native_curves(tmp_path)
    assert sorted(native) == [0, 1, 2] and native[0][0].tolist() == [k * it for k in range(1, 5)]
    steps, lo, hi = pv.band(pv.peer_curves(peer_runs))
    assert steps.tolist() == [k * it for k in range(1, 5)]  # the iterations every Brax seed reached
    rows = pv.band_check(native, (steps, lo, hi))
    assert len(rows) == 4
    for r in rows:  # brute force from the raw rows
        k = r["control_steps"] // it
        peer_vals = [next(x["train_reward_per_step"] for x in peer_runs[s] if x["step"] == k * it) for s in range(3)]
        nat = [json.loads((tmp_path / f"s{s}" / "metrics.jsonl").read_text().splitlines()[k - 1])["avg_reward"]
               for s in range(3)]
        assert r["peer_lo"] == min(peer_vals) and r["peer_hi"] == max(peer_vals)
        assert np.isclose(r["native_mean"], sum(nat) / 3)
        assert r["within"] == (min(peer_vals) <= sum(nat) / 3 <= max(peer_vals))
    det = pv.deterministic_at(peer_runs, 3 * it)
    assert det["per_seed"] == {"0": 3.0, "1": 4.0, "2": 5.0}
    assert np.isclose(det["mean"], 4.0) and np.isclose(det["ci95"], 4.302652729911275 * 1.0 / np.sqrt(3))


def test_native_deterministic_interval_against_scipy():
    from scipy import stats as st

    evals = {s: {"step": 81920, "deterministic": {"avg_reward": v}, "exploring": {"avg_reward": v - 5.0}}
             for s, v in enumerate([7.9, 8.4, 8.1])}
    d = pv.native_deterministic(evals)
    x = np.array([7.9, 8.4, 8.1])
    lo, hi = st.t.interval(0.95, 2, loc=x.mean(), scale=st.sem(x))
    assert np.isclose(d["mean"], x.mean()) and np.isclose(d["ci95"], (hi - lo) / 2)
    assert d["per_seed"] == {"0": 7.9, "1": 8.4, "2": 8.1} and d["steps"]["2"] == 81920
