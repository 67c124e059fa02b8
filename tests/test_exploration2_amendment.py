"""Study 2's amendment A (docs/exploration-study-2.md, nmrl/experiments/exploration2_amendment.py):
its cells against the grid's cells as study 2's own rule makes them from the published rows and
against the published runs' configs, its rule, and its family against scipy's Welch test and
Holm's procedure written out."""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import pathlib

import numpy as np
import pytest
import scipy.stats

from nmrl.experiments import exploration2_amendment as am
from nmrl.experiments import exploration2_rules
from nmrl.experiments.exploration2_cells import ITERATION_S

REPO = pathlib.Path(__file__).resolve().parents[1]
RECORD = REPO / "results" / "exploration2" / "runs"


def _without_budget(cell):
    return dataclasses.replace(cell, name="", steps=None)


@pytest.mark.skipif(not (RECORD / "rows.csv").is_file(), reason="no published record of study 2")
@pytest.mark.parametrize("arm,dt", [("white", 0.02), ("nmp", 0.02), ("white", 0.0025), ("nmp", 0.0025)])
def test_each_family_cell_is_its_grid_cell_at_twice_the_budget(arm, dt):
    """The grid cell study 2's rule makes from the published rows, with the same options, layout
    and seeds, and 32 iterations where the grid had 16; its settings are the published runs'."""
    with open(RECORD / "rows.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    grid = next(c for c in exploration2_rules.later_cells(rows) if c.name == f"grid/dt{dt:g}/{arm}")
    cell = am.family_cell(arm, dt)
    assert _without_budget(cell) == _without_budget(grid) and cell.run_options == grid.run_options
    assert grid.steps == round(16 * ITERATION_S / dt) and cell.steps == 2 * grid.steps
    saved = json.loads((RECORD / "grid" / f"dt{dt:g}" / arm / "points" / "s0" / "config.json").read_text())
    assert cell.settings["sigma"] == saved["sigma"]
    if arm == "nmp":
        assert cell.settings["period_s"] == saved["period_s"]
    assert cell.settings.get("grad_chunks", 1) == (saved.get("grad_chunks") or 1)


def test_wc_holds_w20s_kl_per_second_and_is_w25_otherwise():
    """Wc(2.5)'s clip eps_c: eps_c^2 / 2.5 ms = 0.3^2 / 20 ms (KL per step ~ eps^2, over delta),
    every other option W(2.5)'s."""
    wc, w = am.wc_cell(), am.family_cell("white", 0.0025)
    eps = wc.settings["clip_eps"]
    assert eps ** 2 / 0.0025 == pytest.approx(0.3 ** 2 / 0.02, rel=1e-5)
    others = {k: v for k, v in wc.settings.items() if k != "clip_eps"}
    assert dataclasses.replace(wc, name=w.name, settings=others) == w


def _row(cell: str, seed: int, det: float, speed: float, value: str = "") -> dict:
    return {"cell": cell, "point": f"s{seed}", "seed": str(seed), "value": value, "steps": "10", "budget": "10",
            "diverged": "False", "det_reward_per_s": str(det), "det_forward_speed": str(speed)}


def test_nmp_at_2_5_ms_runs_only_when_nmp_at_20_ms_walks_in_5_of_8():
    name = "amendment/dt0.02/nmp"
    assert am.later([]) == []
    five = [_row(name, s, 100.0, 1.5 if s < 5 else 0.2) for s in range(8)]
    four = [_row(name, s, 100.0, 1.5 if s < 4 else 0.2) for s in range(8)]
    assert [c.name for c in am.later(five)] == ["amendment/dt0.0025/nmp", "amendment/dt0.0025/wc"]
    assert [c.name for c in am.later(four)] == ["amendment/dt0.0025/wc"]


def _holm(p: list[float]) -> list[float]:
    """Holm's adjusted p-values written out: sorted, times (m - rank), running maximum, capped at 1."""
    order = np.argsort(p)
    adj, run = np.empty(len(p)), 0.0
    for rank, i in enumerate(order):
        run = max(run, (len(p) - rank) * p[i])
        adj[i] = min(run, 1.0)
    return list(adj)


def test_the_family_is_welch_and_holm_over_the_contrasts_that_ran():
    """Two-cell contrasts are scipy's Welch t-test; Holm over A1-A5; with NMp(20) walking in 4 of 8,
    A1 and A2 leave the family and Holm runs over A3-A5."""
    rng = np.random.default_rng(0)
    means = {"amendment/dt0.02/white": 100.0, "amendment/dt0.02/nmp": 60.0, "amendment/dt0.0025/white": 200.0,
             "amendment/dt0.0025/nmp": 150.0, "amendment/dt0.0025/wc": 120.0}
    data = {c: m + 30.0 * rng.standard_normal(8) for c, m in means.items()}
    rows = [_row(c, s, v, 2.0) for c, vs in data.items() for s, v in enumerate(vs)]
    fam = {r["contrast"]: r for r in am.family(rows)}
    assert list(fam) == ["A1", "A2", "A3", "A4", "A5"]
    pairs = {"A1": ("amendment/dt0.0025/nmp", "amendment/dt0.0025/white"),
             "A3": ("amendment/dt0.02/nmp", "amendment/dt0.02/white"),
             "A4": ("amendment/dt0.0025/white", "amendment/dt0.02/white"),
             "A5": ("amendment/dt0.0025/wc", "amendment/dt0.02/white")}
    for name, (a, b) in pairs.items():
        t = scipy.stats.ttest_ind(data[a], data[b], equal_var=False)
        assert fam[name]["p"] == pytest.approx(t.pvalue, rel=1e-6)
        assert fam[name]["estimate"] == pytest.approx(data[a].mean() - data[b].mean())
    p = [fam[k]["p"] for k in fam]
    assert [fam[k]["p_holm"] for k in fam] == pytest.approx(_holm(p))
    stand = [r if r["cell"] != "amendment/dt0.02/nmp" or int(r["seed"]) < 4 else {**r, "det_forward_speed": "0.1"}
             for r in rows if r["cell"] != "amendment/dt0.0025/nmp"]
    fam3 = {r["contrast"]: r for r in am.family(stand)}
    assert list(fam3) == ["A3", "A4", "A5"]
    assert [fam3[k]["p_holm"] for k in fam3] == pytest.approx(_holm([fam3[k]["p"] for k in fam3]))
    assert fam3["A3"]["walking"].startswith("4/8")


def test_the_family_waits_for_its_cells():
    rows = [_row("amendment/dt0.02/white", s, 100.0, 2.0) for s in range(8)]
    assert {r["decision"] for r in am.family(rows)} == {"pending"}
    assert math.isclose(am.WC_CLIP, 0.3 / math.sqrt(8))
