"""nmrl.analysis.publish_ppo, the PPO comparison's numbers, on made-up run directories: the iteration
nearest a budget against a brute-force search, the intervals against scipy's t-interval, the curves
against the rows they come from."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats as sps

from nmrl.analysis import publish_ppo as pp
from nmrl.runs import store

ITER = 327_680  # control steps per Brax PPO iteration at the baseline's settings


def _brute_nearest(rows, budget):
    best, best_d = None, None
    positive = [r for r in rows if r["step"] > 0]
    if not positive or max(r["step"] for r in positive) < 0.98 * budget:
        return None
    for r in positive:  # first of the nearest, as min() keeps the first
        d = abs(r["step"] - budget)
        if best_d is None or d < best_d:
            best, best_d = r, d
    return best


@pytest.mark.parametrize("last,budget", list(itertools.product((2, 3, 4, 31, 76, 77), (1e6, 1e7, 2.5e7))))
def test_nearest_row_is_the_nearest_iteration_once_reached(last, budget):
    rows = [{"step": ITER * k} for k in range(last + 1)]
    assert pp.nearest_row(rows, budget) == _brute_nearest(rows, budget)


def test_nearest_row_waits_until_the_budget_is_almost_reached():
    assert pp.nearest_row([{"step": 0}, {"step": 979_999}], 1e6) is None  # 97.99% of 10^6
    assert pp.nearest_row([{"step": 0}, {"step": 980_000}], 1e6) == {"step": 980_000}
    assert pp.nearest_row([{"step": 0}], 1e6) is None


def test_seed_entry_is_the_mean_and_the_95_percent_t_interval():
    by_seed = {2: (30, 4.0, 4.5), 0: (10, 1.0, 1.5), 1: (20, 2.0, 2.0)}
    e = pp.seed_entry(by_seed)
    rew, spd = np.array([4.0, 1.0, 2.0]), np.array([4.5, 1.5, 2.0])
    half = lambda x: sps.t.ppf(0.975, len(x) - 1) * np.std(x, ddof=1) / np.sqrt(len(x))  # noqa: E731
    assert e["seeds"] == [0, 1, 2]
    assert e["avg_reward"] == pytest.approx(rew.mean()) and e["avg_reward_ci95"] == pytest.approx(half(rew))
    assert e["forward_speed"] == pytest.approx(spd.mean()) and e["forward_speed_ci95"] == pytest.approx(half(spd))
    assert e["per_seed"] == [4.0, 1.0, 2.0] and e["control_steps"] == [30, 10, 20]  # in the order given


def test_summary_reads_every_seed_and_leaves_out_budgets_not_reached(tmp_path):
    rng = np.random.default_rng(0)
    lasts = {0: 77, 1: 31, 2: 10}  # seed 2 never reaches 10^7; seed 1 not 2.5*10^7
    for seed, last in lasts.items():
        d = tmp_path / f"ppo_s{seed}"
        d.mkdir()
        for k in range(last + 1):
            store.append_metrics(d, {"step": ITER * k, "eval_avg_reward": float(rng.normal()),
                                     "eval_forward_speed": float(rng.uniform())})
    (tmp_path / "ppo_s3").mkdir()  # a seed without rows is no seed
    runs = pp.ppo_runs(tmp_path)
    assert sorted(runs) == [0, 1, 2]
    ac = {"1e7": {"rows": [{"l": l, "seed": s, "control_steps": 10_112_000, "avg_reward": 4.0 + s,
                            "forward_speed": 4.0} for l in (1, 10) for s in range(3)]}}
    summ = pp.summary(runs, ac)
    for name, budget in pp.BUDGETS.items():
        reached = [s for s, last in lasts.items() if ITER * last >= 0.98 * budget]
        if not reached:
            assert name not in summ["ppo"]
            continue
        e = summ["ppo"][name]
        assert e["seeds"] == reached
        want = [_brute_nearest(runs[s], budget) for s in reached]
        assert e["control_steps"] == [r["step"] for r in want]
        assert e["per_seed"] == [r["eval_avg_reward"] for r in want]
    assert list(summ["ac_l1"]) == ["1e7"] and summ["ac_l10"]["1e7"]["avg_reward"] == pytest.approx(5.0)
    text = pp.table(summ)
    assert text.splitlines()[0] == "| method | 1e6 steps | 1e7 steps | 2.5e7 steps |"
    assert "seed 0 only" in next(x for x in text.splitlines() if x.startswith("| Brax PPO"))  # 2.5e7: seed 0 alone


def test_ac_curves_count_the_control_steps_of_every_environment(tmp_path):
    for l, s, envs in ((1, 0, 32), (10, 2, 8), (30, 0, 32)):
        d = tmp_path / f"l{l}_s{s}"
        d.mkdir()
        store.atomic_write_json(d / store.CONFIG_FILE, {"num_envs": envs})
        for k in (1, 2, 3):
            store.append_metrics(d, {"step": 1000 * k, "avg_reward": 0.5 * k})
    curves = pp.ac_curves(tmp_path)
    assert sorted(curves) == [1, 10]  # l = 30 is not compared
    x, y = curves[10][2]
    assert x.tolist() == [8000.0, 16000.0, 24000.0] and y.tolist() == [0.5, 1.0, 1.5]
