"""The second exploration study's gradient SNR at matched policies in its published record.

``snr.csv`` holds, for white's 20 ms policies of seeds 0-2 after 0, 4, 8 and 16 iterations, each put
at 20, 5 and 2.5 ms and measured with white and with NMp (eq. (1)'s SNR per second of experience), one
row per seed. Once it holds every group, ``snr_summary.csv`` and the doc's SNR table are each group's
mean and 95% t interval over the 3 seeds as scipy computes them from ``snr.csv`` (read with the csv
module alone).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.stats

from nmrl.experiments import exploration2_analysis, kit
from nmrl.experiments.exploration2_cells import SNR_CSV
from tests.test_exploration2_asymptote import _logged
from tests.test_exploration2_record import RECORD, _csv, _doc, _sci

pytestmark = pytest.mark.skipif(not (RECORD / kit.ROWS).is_file(), reason="no published record of study 2")

ITERATIONS, DTS, SEEDS = (0, 4, 8, 16), (0.02, 0.005, 0.0025), (0, 1, 2)
ARMS = {"white": "W", "nmp": "NMp"}  #: snr.csv's arm and the doc's name for it


def _groups() -> dict[tuple[str, int, float], np.ndarray]:
    """Each (arm, iteration, control step)'s SNR per second by seed, once snr.csv holds every group."""
    if not (RECORD / SNR_CSV).is_file():
        pytest.skip("no published SNR of study 2")
    got: dict[tuple[str, int, float], dict[int, float]] = {}
    for r in _csv(RECORD / SNR_CSV):
        got.setdefault((r["arm"], int(r["iteration"]), float(r["control_dt"])), {})[int(r["seed"])] = float(r["snr_per_s"])
    want = {(a, it, dt) for a in ARMS for it in ITERATIONS for dt in DTS}
    if set(got) != want or any(sorted(v) != list(SEEDS) for v in got.values()):
        pytest.skip("the SNR measurement has not finished in the record")
    return {k: np.array([v[s] for s in SEEDS]) for k, v in got.items()}


def _t(x: np.ndarray) -> tuple[float, float, float]:
    lo, hi = scipy.stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=scipy.stats.sem(x))
    return float(x.mean()), float(lo), float(hi)


def _g(x: float) -> str:
    """A number as the doc's SNR table writes it: the record's :func:`_sci` (1.8·10⁻²), the minus
    sign U+2212."""
    return _sci(x).replace("-", "\N{MINUS SIGN}")


@pytest.mark.parametrize("it", (1, 4, 8))
def test_the_matched_policies_are_the_grids_w20_runs_after_their_iterations(it):
    """The SNR's policies after 1, 4 and 8 iterations are cells of their own (white at 20 ms, seeds
    0-2) with W(20)'s settings but the budget (and grad_chunks, which W(20)'s config lacks, at 1: one
    gradient per minibatch, as W(20) took it): each run logs what W(20)'s run of its seed logged in
    its first iterations, every metric to the bit (the wall times aside), so the measured policies are
    the grid's runs at those iterations, as Progress says."""
    cell = RECORD / "snr" / "dt0.02" / f"white_it{it}" / "points"
    if not cell.is_dir():
        pytest.skip(f"the SNR's iteration-{it} cell is not in the record")
    grid = RECORD / "grid" / "dt0.02" / "white" / "points"
    assert sorted(p.name for p in cell.iterdir()) == [f"s{s}" for s in SEEDS]
    for p in cell.iterdir():
        a, g = (json.loads((d / p.name / "config.json").read_text()) for d in (cell, grid))
        assert {k for k in a.keys() | g.keys() if a.get(k) != g.get(k)} <= {"steps", "grad_chunks"}
        assert a["steps"] == it * 5120 and a.get("grad_chunks", 1) == 1  # W(20)'s config predates grad_chunks
        mine = _logged(p)
        assert len(mine) == it and mine == _logged(grid / p.name)[:it], p.name
    assert "The matched-SNR cells finished" in _doc()


def test_the_snr_summary_is_the_t_interval_of_each_group_over_the_seeds():
    groups = _groups()
    table = {(r["arm"], int(r["iteration"]), float(r["control_dt"])): r
             for r in _csv(RECORD / exploration2_analysis.SNR_SUMMARY_CSV)}
    assert set(table) == set(groups)
    for k, x in groups.items():
        mean, lo, hi = _t(x)
        assert [float(table[k][c]) for c in ("mean", "ci_lo", "ci_hi")] == pytest.approx([mean, lo, hi], rel=1e-9), k


def test_the_docs_snr_table_is_the_t_interval_of_each_group_over_the_seeds():
    """A row per policy iteration and arm: | iteration | arm | 20 ms | 5 ms | 2.5 ms |, each cell the
    mean [95% t interval] over the seeds."""
    groups, doc = _groups(), _doc()
    for it in ITERATIONS:
        for arm, name in ARMS.items():
            cells = " | ".join("{} [{}, {}]".format(*map(_g, _t(groups[arm, it, dt]))) for dt in DTS)
            row = f"| {it} | {name} | {cells} |"
            assert row in doc, row
