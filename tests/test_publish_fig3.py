"""nmrl.analysis.publish_fig3, Fig. 3's plain answers and progress page, on made-up progress records:
the l = 10 against l = 1 difference against a Welch interval computed here from scipy's t quantile
and the Welch-Satterthwaite degrees of freedom, the best l against a plain max, the page against the
record it is written from."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from nmrl.analysis import publish_fig3 as pf

MS = [str(m) for m in pf.MILESTONES]


def _welch(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    df = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    return b.mean() - a.mean(), sps.t.ppf(0.975, df) * np.sqrt(va + vb)


def _record(values: dict) -> dict:
    """A progress record: ``values`` = {l: {milestone: [seed values or None]}}."""
    by_l = {}
    for l, per in values.items():
        by_l[str(l)] = {}
        for m in MS:
            seeds = per.get(m, [None, None, None])
            ok = all(v is not None for v in seeds)
            by_l[str(l)][m] = {"seeds": seeds, "mean": float(np.mean(seeds)) if ok else None,
                               "ci95": 0.1 if ok else 0.0}
    points = {f"l{l}_s{s}": {"trials": 100_000, "budget_share": 1.0, "collapsed": (l, s) == (30, 1)}
              for l in values for s in range(3)}
    return {"milestones": list(pf.MILESTONES), "by_l": by_l, "points": points,
            "diverged": [{"point": "l30_s2", "trials": 41_000}], "rate_ctrl_steps_per_s": 16_000.0,
            "remaining_ctrl_steps": 0}


RNG = np.random.default_rng(7)
VALUES = {l: {m: list(np.round(RNG.normal(1.0 + 0.3 * i + 0.1 * l, 0.5, 3), 3)) for i, m in enumerate(MS)}
          for l in (1, 10, 30)}
VALUES[30][MS[-1]] = [2.0, None, 2.5]  # one seed of l = 30 short of 10^5


def test_l10_against_l1_is_the_difference_of_means_with_the_welch_interval():
    a = pf.answers(_record(VALUES), ls=[1, 10, 30])
    assert sorted(a["l10_vs_l1"]) == sorted(MS)
    for m in MS:
        d, h = _welch(VALUES[1][m], VALUES[10][m])
        e = a["l10_vs_l1"][m]
        assert e["diff"] == pytest.approx(d) and e["diff_ci95"] == pytest.approx(h)
        assert e["l1"] == pytest.approx(np.mean(VALUES[1][m])) and e["l10"] == pytest.approx(np.mean(VALUES[10][m]))
        l1 = np.mean(VALUES[1][m])
        assert e["relative"] == (pytest.approx(np.mean(VALUES[10][m]) / l1 - 1) if l1 > 0 else None)


def test_best_l_is_the_highest_mean_among_the_l_that_reached_the_milestone():
    a = pf.answers(_record(VALUES), ls=[1, 10, 30])
    for m in MS:
        reached = {l: np.mean(v[m]) for l, v in VALUES.items() if all(x is not None for x in v[m])}
        best = max(reached, key=reached.get)
        assert a["best_l"][m] == {"l": best, "mean": pytest.approx(reached[best]), "among": sorted(reached)}
    assert a["best_l"][MS[-1]]["among"] == [1, 10]  # l = 30 has a seed short of 10^5


def test_l30_lists_its_divergences_and_collapses_only_when_the_sweep_has_l30():
    rec = _record(VALUES)
    assert pf.answers(rec, ls=[1, 10, 30])["l30"] == {"diverged": [{"point": "l30_s2", "trials": 41_000}],
                                                      "collapsed": ["l30_s1"]}
    assert "l30" not in pf.answers(rec, ls=[1, 10])


def test_progress_page_reads_the_record():
    rec = _record(VALUES)
    rec["answers"] = pf.answers(rec, ls=[1, 10, 30])
    md = pf.progress_md(rec)
    row10 = next(x for x in md.splitlines() if x.startswith("| 10 |"))
    for m in MS:
        e = rec["by_l"]["10"][m]
        assert f"{e['mean']:+.2f} ± {e['ci95']:.2f}" in row10
    assert "Diverged: l30_s2 at 41,000 trials." in md
    assert "Collapsed (last tenth below half the running peak): l30_s1." in md
    e = rec["answers"]["l10_vs_l1"][MS[-1]]
    assert f"- 100,000 trials: {e['l10']:+.2f} vs {e['l1']:+.2f}, difference {e['diff']:+.2f} ± {e['diff_ci95']:.2f}" in md
