"""The second exploration study's asymptote (white and CN at 5 ms, 4x the grid's budget) in its published record.

The white cell is W(5) with 4x the budget: its runs repeat W(5)'s within W(5)'s budget, every metric
to the bit, so W(5)'s endpoints are the same runs' endpoints after 16 iterations, and the doc's gain
from 16 to 64 iterations is scipy's paired t interval of the two rows.csv columns by seed; the doc's
learning-curve means and slopes are NumPy's from the runs' metrics.jsonl (the exploring reward per
second, avg_reward / 0.02 s as rows.csv's).
"""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest
import scipy.optimize
import scipy.stats

from nmrl.experiments import kit
from tests.doc_numbers import assert_numbers, normalised
from tests.test_exploration2_record import LATER, RECORD, _csv, _doc, _finished, _n, _welch
from tests.test_exploration2_secondary import _readme

pytestmark = pytest.mark.skipif(not (RECORD / kit.ROWS).is_file(), reason="no published record of study 2")

WHITE = RECORD / LATER["W(5) 64 it"] / "points"


def _metrics(point: pathlib.Path) -> list[dict]:
    return [json.loads(line) for line in (point / "metrics.jsonl").read_text().splitlines()]


def _logged(point: pathlib.Path) -> list[dict]:
    """A run's metrics without its clock (wall time and speed): what two runs of one setting share."""
    return [{k: v for k, v in m.items() if k not in {"wall_s", "steps_per_s"}} for m in _metrics(point)]


def test_the_asymptotes_white_runs_repeat_the_grids_w5_within_its_budget():
    """The asymptote's white cell is W(5) with 4x the budget (its runs' configs differ in the budget
    alone), and nothing in PPO depends on the budget: each run's first 16 iterations log what W(5)'s
    run of the same seed logged, every metric to the bit (their wall times aside), as the doc's
    Progress says. Both cells ran on one machine; skipped until the record holds 16 iterations."""
    grid = RECORD / LATER["W(5)"] / "points"
    logs = {p.name: _metrics(p) for p in WHITE.iterdir()} if WHITE.is_dir() else {}
    if not logs or any(len(m) < 16 for m in logs.values()):
        pytest.skip("the asymptote's white runs have not logged 16 iterations in the record")
    assert sorted(logs) == sorted(p.name for p in grid.iterdir())
    for name in logs:
        a, g = (json.loads((d / name / "config.json").read_text()) for d in (WHITE, grid))
        assert {k for k in a.keys() | g.keys() if a.get(k) != g.get(k)} == {"steps"}
        assert a["steps"] == 4 * g["steps"]
        mg = _logged(grid / name)
        assert len(mg) == 16
        assert _logged(WHITE / name)[:16] == mg, name


def _by_seed(cell: str) -> dict[int, float]:
    return {int(r["seed"]): float(r["det_reward_per_s"]) for r in _csv(RECORD / kit.ROWS) if r["cell"] == cell}


def test_the_docs_gain_from_16_to_64_iterations_is_a_paired_t_interval_of_the_rows():
    """Each white run's endpoint after 64 iterations minus its W(5) run's (the same run after 16):
    the doc's mean, 95% t interval over the seeds and range of the per-seed gains."""
    if _finished(LATER["W(5) 64 it"]) is None:
        pytest.skip("the asymptote's white cell has not finished in the record")
    late, early = _by_seed(LATER["W(5) 64 it"]), _by_seed(LATER["W(5)"])
    assert sorted(late) == sorted(early) == [0, 1, 2, 3]
    a, b = (np.array([d[s] for s in sorted(late)]) for d in (late, early))
    ci = scipy.stats.ttest_rel(a, b).confidence_interval(0.95)
    d = a - b
    assert_numbers(_doc(), [_n(d.mean()), _n(ci.low), _n(ci.high), _n(d.min()), _n(d.max())], window=120)


@pytest.mark.parametrize("arm,name,title", [("white", "W(5) 64 it", "W at 5 ms"), ("colored", "CN(5) 64 it", "CN at 5 ms")])
def test_the_docs_asymptote_curves_are_the_runs_metrics(arm, name, title):
    """Each arm's Progress bullet gives its exploring reward per second (each iteration's avg_reward /
    0.02 s) averaged over the seeds after 16, 32, 48 and 64 iterations, and the range of each run's
    least-squares slope over the last 16 iterations (np.polyfit)."""
    if _finished(LATER[name]) is None:
        pytest.skip(f"{name} has not finished in the record")
    points = RECORD / LATER[name] / "points"
    curves = np.array([[m["avg_reward"] / 0.02 for m in _metrics(p)] for p in sorted(points.iterdir())])
    assert curves.shape == (4, 64)
    means = [_n(curves[:, i - 1].mean()) for i in (16, 32, 48, 64)]
    slopes = [np.polyfit(np.arange(49, 65), c[48:], 1)[0] for c in curves]
    bullet = normalised(_doc()).split(f"* {title} with 4× the budget finished", 1)[1].split(" * ", 1)[0]
    assert_numbers(bullet, means, window=60)
    assert_numbers(bullet, [_n(min(slopes), digits=2), _n(max(slopes), digits=2)], window=20)


def test_the_docs_asymptote_check_is_welch_and_power_of_the_rows():
    """The Results' asymptote check: both cells' means and W(5)'s, CN minus W (in the README too:
    scipy Welch 95%, "not detected" as its interval holds 0), CN minus W on the exploring reward
    over the last iteration and over the run (scipy Welch 95%), and the difference 4 seeds detect
    with 80% power at the two cells' pooled SD (a two-sided t test, 6 degrees of freedom, scipy's
    noncentral t)."""
    cn, w = _finished(LATER["CN(5) 64 it"]), _finished(LATER["W(5) 64 it"])
    if cn is None or w is None:
        pytest.skip("the asymptote's cells have not finished in the record")
    section = _doc().split("### The asymptote, checked", 1)[1].split("###", 1)[0]
    assert_numbers(section, [_n(w.mean()), _n(cn.mean()), _n(_finished(LATER["W(5)"]).mean())], window=80)
    secondary = []
    for key in ("avg_reward_per_s", "auc_reward_per_s"):
        e, lo, hi, _ = _welch(_finished(LATER["CN(5) 64 it"], key), _finished(LATER["W(5) 64 it"], key))
        secondary += [_n(e), _n(lo), _n(hi)]
    assert_numbers(section, secondary, window=120)
    sd = np.sqrt((cn.var(ddof=1) + w.var(ddof=1)) / 2)
    tc = scipy.stats.t.ppf(0.975, 6)

    def power(d):
        nc = d / (sd * np.sqrt(2 / 4))
        return scipy.stats.nct.sf(tc, 6, nc) + scipy.stats.nct.cdf(-tc, 6, nc)

    e, lo, hi, _ = _welch(cn, w)
    assert lo < 0 < hi
    assert_numbers(_readme(), [_n(e), _n(lo), _n(hi)], window=40)
    d80 = scipy.optimize.brentq(lambda d: power(d) - 0.8, 1e-6, 6 * sd)
    assert_numbers(section, [_n(sd), f"{d80:.0f}"], window=80)
