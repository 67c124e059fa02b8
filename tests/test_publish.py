"""The paper-scale Fig. 3 publisher's plain answers (scripts/publish_fig3_paper.py), on made-up
per-seed milestone values, against scipy's Welch interval and a direct reading of the table."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
from scipy import stats as sps

from nmrl.experiments import sweep
from nmrl.paper.learner import TrainConfig

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "scripts" / "publish_fig3_paper.py"


def _publisher():
    spec = importlib.util.spec_from_file_location("publish_fig3_paper", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _entry(seeds):
    got = [v for v in seeds if v is not None]
    return {"mean": float(np.mean(got)) if len(got) == len(seeds) else None, "ci95": 0.0, "seeds": seeds}


def test_answers_compare_l10_with_l1_and_name_the_best_l():
    pub = _publisher()
    spec = sweep.SweepSpec(ls=(1, 10, 30), seeds=3, base=TrainConfig(trials=100_000))
    none = [None, None, None]
    table = {  # l -> milestone -> seeds
        "1": {"10000": [-0.1, -1.4, 0.0], "20000": [1.3, 2.2, 2.3], "30000": [2.9, 3.0, 3.3], "100000": [3.2, 3.3, 3.4]},
        "10": {"10000": [1.2, 1.1, 1.0], "20000": [2.2, 2.0, 1.9], "30000": [3.3, 2.7, 2.7], "100000": [4.5, 4.6, 4.7]},
        "30": {"10000": [0.6, 1.2, 0.6], "20000": [1.1, 2.0, 1.4], "30000": [1.7, 2.4, 2.0], "100000": none},
    }
    points = {f"l{l}_s{s}": {"trials": 100_000 if l != 30 else 40_000, "budget_share": 1.0 if l != 30 else 0.4,
                             "collapsed": False} for l in spec.ls for s in range(3)}
    points["l30_s0"]["collapsed"] = points["l1_s0"]["collapsed"] = True
    p = {"by_l": {l: {m: _entry(v) for m, v in by.items()} for l, by in table.items()}, "points": points,
         "diverged": [{"point": "l30_s2", "trials": 12_345, "step": 99_000}]}
    a = pub.answers(p, spec)
    for m in ("10000", "20000", "30000", "100000"):
        e = a["l10_vs_l1"][m]
        lo, hi = sps.ttest_ind(table["10"][m], table["1"][m], equal_var=False).confidence_interval(0.95)
        assert np.isclose(e["diff"] - e["diff_ci95"], lo) and np.isclose(e["diff"] + e["diff_ci95"], hi)
    assert a["l10_vs_l1"]["10000"]["relative"] is None  # l = 1 below zero: no ratio
    assert np.isclose(a["l10_vs_l1"]["100000"]["relative"], 4.6 / 3.3 - 1)
    assert a["best_l"]["30000"] == {"l": 1, "mean": np.mean(table["1"]["30000"]), "among": [1, 10, 30]}
    assert a["best_l"]["100000"]["l"] == 10 and a["best_l"]["100000"]["among"] == [1, 10]  # l = 30 not there yet
    assert a["l30"] == {"diverged": [p["diverged"][0]], "collapsed": ["l30_s0"]}
    md = pub.progress_md({**p, "milestones": [10_000, 20_000, 30_000, 100_000], "rate_ctrl_steps_per_s": 1e4,
                          "answers": a})
    assert "- 100,000 trials: +4.60 vs +3.30" in md and "+39%" in md
    assert "Collapsed (last tenth below half the running peak): l1_s0, l30_s0." in md
    assert "| 30 |" in md and "40,000 (40.0%)" in md
