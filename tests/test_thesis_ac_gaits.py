"""The gaits of study 3 (nmrl/experiments/thesis_ac.py, ``gait_picks`` and ``gaits``): which arm and
run are drawn, against a ranking and a median computed here with ``statistics``, and, on a published
20 ms policy of the paper's actor-critic, that the rollout covers 10 s and is made once per saved step."""

from __future__ import annotations

import json
import pathlib
import shutil
import statistics

import numpy as np
import pytest

from nmrl.experiments import kit_gaits, thesis_ac

REPO = pathlib.Path(__file__).resolve().parents[1]
POINT = REPO / "results/thesis_ac/grid/dt0.02/points/stationary_s0"

REWARDS = {"stationary": [10.0, -5.0, 40.0, 22.0, 7.0, 30.0, 1.0, 12.0],
           "p0.1s": [50.0, 60.0, 5.0, 45.0, 70.0, 52.0, 48.0, 90.0],
           "p0.2s": [55.0, 61.0, 35.0, 40.0, 44.0, 58.0, 49.0, 20.0]}


def _rows(rewards, dt=0.0025):
    return [{"cell": f"grid/dt{dt:g}", "point": f"{arm}_s{i}", "seed": str(i), "control_dt": str(dt), "steps": "10",
             "budget": "10", "diverged": "False", "det_reward_per_s": str(r)}
            for arm, rs in rewards.items() for i, r in enumerate(rs)]


def test_the_stationary_and_the_best_nm_period_arms_median_runs():
    stationary, best = thesis_ac.gait_picks(_rows(REWARDS))
    means = {a: statistics.fmean(r) for a, r in REWARDS.items()}
    assert best["arm"] == max(("p0.1s", "p0.2s"), key=means.get) == "p0.1s" and best["name"] == "best_p0.1s"
    assert stationary["arm"] == stationary["name"] == "stationary"
    for c in (stationary, best):
        rs = REWARDS[c["arm"]]
        assert c["det_reward_per_s"] == statistics.median_low(rs)
        assert c["point"] == f"{c['arm']}_s{rs.index(statistics.median_low(rs))}"
        assert c["cell"] == "grid/dt0.0025" and c["cell_mean"] == pytest.approx(means[c["arm"]])


def test_waits_for_the_whole_cell_and_reads_only_its_control_step():
    rows = _rows(REWARDS)
    rows[3]["steps"] = "5"  # one run not at its budget: the cell is incomplete
    assert thesis_ac.gait_picks(rows) is None
    rows[3]["diverged"] = "True"  # a diverged run is final (scored by its last good policy)
    assert thesis_ac.gait_picks(rows) is not None
    assert thesis_ac.gait_picks(_rows(REWARDS, dt=0.02)) is None  # the 20 ms cell alone draws nothing
    other = {a: [r + 1000 for r in rs] for a, rs in REWARDS.items()}
    picks = thesis_ac.gait_picks(_rows(REWARDS) + _rows(other, dt=0.02))
    assert [c["det_reward_per_s"] for c in picks] == [statistics.median_low(REWARDS[c["arm"]]) for c in picks]


def test_the_study_draws_its_gaits_after_its_cells():
    assert [m.file for m in thesis_ac.STUDY.measurements] == [kit_gaits.GAITS]


def test_a_published_policy_is_rolled_out_for_ten_seconds_once_per_step(tmp_path):
    if not POINT.is_dir():
        pytest.skip("the published 20 ms stationary run is not in this checkout")
    shutil.copytree(POINT, tmp_path / "grid/dt0.02/points/stationary_s0")
    pick = {"name": "stationary", "arm": "stationary", "cell": "grid/dt0.02", "point": "stationary_s0", "seed": 0}
    kit_gaits.draw(tmp_path, [pick], lambda c: "l = 1")
    step = json.loads((POINT / "endpoint.json").read_text())["step"]
    (s,) = json.loads((tmp_path / "gaits" / "gaits.json").read_text())
    assert s["step"] == step and "name" not in s and s["point"] == "stationary_s0"
    d = tmp_path / "gaits" / "stationary"
    with np.load(d / "trajectory.npz") as t:
        assert float(t["control_dt"]) == 0.02 and t["pos"].shape == (501, 10, 2) and np.all(np.isfinite(t["pos"]))
    ev = json.loads((d / "eval.json").read_text())
    assert ev["seconds"] == 10.0 and ev["steps"] == 500 and ev["step"] == step
    assert s["forward_speed"] == ev["deterministic"]["forward_speed"]
    assert (d / kit_gaits.STROBE_10S).stat().st_size > 0 and (d / "gait.gif").stat().st_size > 0
    made = (d / "eval.json").stat().st_mtime_ns
    kit_gaits.draw(tmp_path, [pick], lambda c: "l = 1")
    assert (d / "eval.json").stat().st_mtime_ns == made
