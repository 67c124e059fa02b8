"""The publishers' plain answers and tables, on made-up values: the paper-scale Fig. 3
(scripts/publish/publish_fig3_paper.py) against scipy's Welch interval and a direct reading of the table;
the PPO comparison's table (scripts/publish/publish_baseline_ppo.py) against scipy's t-interval."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
import pytest
from scipy import stats as sps

from nmrl import options
from nmrl.experiments import sweep
from nmrl.learners.ac_config import TrainConfig
from nmrl.runs import store

SCRIPTS = pathlib.Path(__file__).resolve().parents[1] / "scripts"


def _publisher(name: str = "publish/publish_fig3_paper"):
    spec = importlib.util.spec_from_file_location(pathlib.Path(name).name, SCRIPTS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _entry(seeds):
    got = [v for v in seeds if v is not None]
    return {"mean": float(np.mean(got)) if len(got) == len(seeds) else None, "ci95": 0.0, "seeds": seeds}


def test_answers_compare_l10_with_l1_and_name_the_best_l():
    pub = _publisher()
    spec = sweep.SweepSpec(ls=(1, 10, 30), seeds=3, base=options.build(TrainConfig, trials=100_000))
    none = [None, None, None]
    table = {  # l -> milestone -> seeds
        "1": {"10000": [-0.1, -1.4, 0.0], "20000": [1.3, 2.2, 2.3], "30000": [2.9, 3.0, 3.3], "50000": [3.0, 3.1, 3.3],
              "100000": [3.2, 3.3, 3.4]},
        "10": {"10000": [1.2, 1.1, 1.0], "20000": [2.2, 2.0, 1.9], "30000": [3.3, 2.7, 2.7], "50000": [4.0, 3.6, 3.9],
               "100000": [4.5, 4.6, 4.7]},
        "30": {"10000": [0.6, 1.2, 0.6], "20000": [1.1, 2.0, 1.4], "30000": [1.7, 2.4, 2.0], "50000": none,
               "100000": none},
    }
    points = {f"l{l}_s{s}": {"trials": 100_000 if l != 30 else 40_000, "budget_share": 1.0 if l != 30 else 0.4,
                             "collapsed": False} for l in spec.ls for s in range(3)}
    points["l30_s0"]["collapsed"] = points["l1_s0"]["collapsed"] = True
    p = {"by_l": {l: {m: _entry(v) for m, v in by.items()} for l, by in table.items()}, "points": points,
         "diverged": [{"point": "l30_s2", "trials": 12_345, "step": 99_000}]}
    a = pub.answers(p, spec)
    for m in ("10000", "20000", "30000", "50000", "100000"):
        e = a["l10_vs_l1"][m]
        lo, hi = sps.ttest_ind(table["10"][m], table["1"][m], equal_var=False).confidence_interval(0.95)
        assert np.isclose(e["diff"] - e["diff_ci95"], lo) and np.isclose(e["diff"] + e["diff_ci95"], hi)
    assert a["l10_vs_l1"]["10000"]["relative"] is None  # l = 1 below zero: no ratio
    assert np.isclose(a["l10_vs_l1"]["100000"]["relative"], 4.6 / 3.3 - 1)
    assert a["best_l"]["30000"] == {"l": 1, "mean": np.mean(table["1"]["30000"]), "among": [1, 10, 30]}
    assert a["best_l"]["50000"] == {"l": 10, "mean": np.mean(table["10"]["50000"]), "among": [1, 10]}
    assert a["best_l"]["100000"]["l"] == 10 and a["best_l"]["100000"]["among"] == [1, 10]  # l = 30 not there yet
    assert a["l30"] == {"diverged": [p["diverged"][0]], "collapsed": ["l30_s0"]}
    md = pub.progress_md({**p, "milestones": [10_000, 20_000, 30_000, 50_000, 100_000], "rate_ctrl_steps_per_s": 1e4,
                          "answers": a})
    assert "- 100,000 trials: +4.60 vs +3.30" in md and "+39%" in md
    assert "Collapsed (last tenth below half the running peak): l1_s0, l30_s0." in md
    assert "| 30 |" in md and "40,000 (40.0%)" in md


def test_ppo_table_gives_an_interval_only_over_seeds():
    """One PPO seed at a budget: its value and 'seed N only', never a '± 0.00' interval; three
    seeds: mean ± the 95% t-interval; a budget not reached: a dash."""
    pub = _publisher("publish/publish_baseline_ppo")
    rows = {0: [{"step": 327_680 * k, "eval_avg_reward": -1.0 + 0.1 * k, "eval_forward_speed": 0.1 * k}
                for k in range(0, 4)]}
    ac = {"1e6": {"rows": [{"l": l, "seed": s, "control_steps": 1_000_000, "avg_reward": v, "forward_speed": 1.0}
                           for l in (1, 10) for s, v in enumerate((1.0, 2.0, 4.0))]}}
    summ = pub.summary(rows, ac)
    text = pub.table(summ)
    ppo = next(x for x in text.splitlines() if x.startswith("| Brax PPO"))
    assert "-0.70, seed 0 only (0.30 m/s)" in ppo and "±" not in ppo  # iteration 3 (983,040) is nearest 10^6
    assert ppo.count("—") == 2
    half = sps.t.ppf(0.975, 2) * np.std([1.0, 2.0, 4.0], ddof=1) / np.sqrt(3)
    l1 = next(x for x in text.splitlines() if x.startswith("| actor-critic, l = 1 "))
    assert f"+2.33 ± {half:.2f} (1.00 m/s)" in l1


def test_ppo_seed_is_published_with_its_parameters_only_while_unfinished(tmp_path):
    """A seed short of its budget is published with compact.npz (a fresh clone continues it); once
    finished, its config, metrics and resumes only, and the compact.npz published earlier is removed."""
    import dataclasses
    import json

    from nmrl.experiments import baseline_config as bc

    pub = _publisher("publish/publish_baseline_ppo")
    cfg = bc.BaselineConfig(num_timesteps=120, num_envs=4, batch_size=4, num_minibatches=2, unroll_length=5)
    assert cfg.steps_per_iteration == 40 and cfg.iterations == 3
    src, dest = tmp_path / "runs" / "ppo_s0", tmp_path / "results" / "ppo_s0"
    src.mkdir(parents=True)
    d = dataclasses.asdict(cfg)
    d["policy_hidden"], d["value_hidden"] = list(cfg.policy_hidden), list(cfg.value_hidden)
    store.atomic_write_json(src / store.CONFIG_FILE, d)
    (src / store.COMPACT_FILE).write_bytes(b"parameters")
    (src / store.RESUMES_FILE).write_text(json.dumps({"from_step": 40}) + "\n")
    for step in (0, 40, 80):
        store.append_metrics(src, {"step": step})
    pub.publish_seed(src, dest)
    assert sorted(f.name for f in dest.iterdir()) == sorted(
        [store.CONFIG_FILE, store.METRICS_FILE, store.RESUMES_FILE, store.COMPACT_FILE])
    assert (dest / store.COMPACT_FILE).read_bytes() == b"parameters"
    store.append_metrics(src, {"step": 120})  # the budget's third iteration: finished
    pub.publish_seed(src, dest)
    assert sorted(f.name for f in dest.iterdir()) == sorted([store.CONFIG_FILE, store.METRICS_FILE, store.RESUMES_FILE])
    assert [r["step"] for r in store.read_metrics(dest)] == [0, 40, 80, 120]
    # published in place (SRC = DEST): the same rule
    (dest / store.COMPACT_FILE).write_bytes(b"stale")
    pub.publish_seed(dest, dest)
    assert not (dest / store.COMPACT_FILE).exists()


def test_progress_counts_the_steps_left_and_the_hours_at_the_measured_rate(tmp_path):
    """Made-up metrics: a finished point, a running one, a diverged one and one not started. Left:
    the running point's missing trials at its own trial length so far, plus the unstarted point's
    whole budget at the stop rule's mean length (1/stop_prob); hours at the running point's rate."""
    pub = _publisher()
    spec = sweep.SweepSpec(ls=(1, 10), seeds=2, base=options.build(TrainConfig, trials=1000, num_envs=8, stop_prob=1 / 250))

    def write(l, s, rows):
        d = sweep.point_dir(tmp_path, l, s)
        d.mkdir(parents=True)
        for r in rows:
            store.append_metrics(d, {"avg_reward": 1.0, "diverged": False, "theta_norm": 1.0, "v_norm": 1.0, **r})

    write(1, 0, [{"trials": 1000, "step": 30_000, "steps_per_s": 900.0}])  # finished
    write(1, 1, [{"trials": 100 * k, "step": 4_000 * k, "steps_per_s": 1_000.0 + k} for k in range(1, 5)])
    write(10, 0, [{"trials": 50, "step": 2_000, "steps_per_s": 1_000.0, "diverged": True}])  # diverged: never ends
    sweep.point_dir(tmp_path, 10, 1).mkdir(parents=True)  # not started
    p = pub.progress(tmp_path, spec)
    running_left = (1000 - 400) * (16_000 * 8 / 400)  # 320 control steps per trial over 8 environments
    unstarted_left = 1000 * 250
    assert p["rate_ctrl_steps_per_s"] == np.median([1_001.0, 1_002.0, 1_003.0, 1_004.0])
    assert np.isclose(p["remaining_ctrl_steps"], running_left + unstarted_left)
    assert np.isclose(p["remaining_hours_at_rate"], (running_left + unstarted_left) / 1_002.5 / 3600)
    assert f"Left: ~{running_left + unstarted_left:,.0f} control steps" in pub.progress_md(p)


def test_progress_reports_each_points_largest_fall_and_the_worst_per_l(tmp_path):
    """A curve that rises to 4, falls to 1 and comes back to 3 (chunks of 10^4 trials, smoothed over
    5): the row of its l names the fall of the running mean from its peak and where; a steady
    seed's fall is 0; the worst per l is the first column."""
    pub = _publisher()
    spec = sweep.SweepSpec(ls=(20,), seeds=2, base=options.build(TrainConfig, trials=200_000, num_envs=8))
    curves = {0: [4.0] * 10 + [1.0] * 5 + [3.0] * 5, 1: [2.0] * 20}
    for s, ys in curves.items():
        d = sweep.point_dir(tmp_path, 20, s)
        d.mkdir(parents=True)
        for k, y in enumerate(ys, 1):
            store.append_metrics(d, {"avg_reward": y, "diverged": False, "theta_norm": 1.0, "v_norm": 1.0,
                                     "trials": 10_000 * k, "step": 1_000 * k, "steps_per_s": 1_000.0})
    p = pub.progress(tmp_path, spec)
    f0 = p["points"]["l20_s0"]["largest_fall"]
    # the 5-chunk mean reaches 1.0 at chunk 15 (150,000 trials); the peak 4.0 first at chunk 1
    assert (f0["fall"], f0["peak_trials"], f0["trough_trials"], f0["end"]) == (3.0, 10_000, 150_000, 3.0)
    assert p["points"]["l20_s1"]["largest_fall"]["fall"] == 0.0
    md = pub.progress_md(p)
    assert "| 20 | 3.00 | l20_s0: 3.00 (75%): +4.00 at 10,000 → +1.00 at 150,000, end +3.00; l20_s1: 0.00 (0%)" in md


def test_fig3_milestone_lines_hold_only_the_l_whose_every_seed_reached_them(tmp_path):
    from nmrl.analysis import plots

    # l = 2 has one seed short of 3*10^4 and none at 10^5; 10^5: l = 1 and 10 only; 2*10^5: nobody
    by_l = {"1": {"10000": _entry([0.1, 0.2, 0.3]), "30000": _entry([3.0, 3.1, 3.2]), "100000": _entry([4.7, 4.8, 4.9])},
            "2": {"10000": _entry([0.5, 0.4, 0.6]), "30000": _entry([3.3, None, 3.2]), "100000": _entry([None] * 3)},
            "10": {"10000": _entry([1.1, 1.0, 1.2]), "30000": _entry([2.9, 2.8, 3.0]), "100000": _entry([4.2, 4.3, 4.4])}}
    series = plots.milestone_series(by_l, (10_000, 30_000, 100_000, 200_000))
    assert [s["trials"] for s in series] == [10_000, 30_000, 100_000]
    assert series[0]["l"] == [1, 2, 10] and np.allclose(series[0]["mean"], [0.2, 0.5, 1.1])
    assert series[1]["l"] == [1, 10] and np.allclose(series[1]["mean"], [3.1, 2.9])
    assert series[2]["l"] == [1, 10] and np.allclose(series[2]["mean"], [4.8, 4.3])
    path = plots.fig3_milestones(by_l, (10_000, 30_000, 100_000), tmp_path / "fig3.png")
    assert path.stat().st_size > 10_000


def test_physics_fidelity_reads_a_published_point(tmp_path, capsys):
    """The fidelity script's default policy is a published compact state (a clean clone has no
    checkpoints); a folder with neither checkpoints nor a compact state is refused by name."""
    fid = _publisher("lab/physics_fidelity")
    a = fid.parse_args([])
    assert (a.run_dir / "compact.npz").is_file() and not (a.run_dir / "checkpoints").exists()
    with pytest.raises(SystemExit):
        fid.parse_args(["--run-dir", str(tmp_path)])
    err = capsys.readouterr().err
    assert f"--run-dir {tmp_path}" in err and "compact.npz" in err


def test_fast_preset_baseline_is_the_published_fig3_fast_sweep():
    """The fast-preset publisher reads its baseline, the published reduced sweep, in the sweeps'
    layout (points/l<l>_s<seed>/metrics.jsonl): all 24 points, each with every row of its file."""
    import json

    pub = _publisher("publish/publish_fast_preset")
    got = pub.points_of(pub.BASELINE)
    root = pathlib.Path(__file__).resolve().parents[1] / "results" / "fig3_fast" / "points"
    want = {}
    for d in sorted(root.iterdir()):
        l, s = d.name[1:].split("_s")
        want[(int(l), int(s))] = [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines() if x.strip()]
    assert len(want) == 24 and got == want
