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


@pytest.mark.skipif(not (RECORD / "rows.csv").is_file(), reason="no published record of study 2")
def test_a_run_that_repeats_the_grids_16_iterations_is_found_identical_and_one_that_does_not_is_named(tmp_path):
    """continuation(): a run whose first 16 metrics rows are the grid's (its wall times aside, and
    iterations past 16 ignored) is identical; one metric changed at iteration 5 is named with its
    relative difference."""
    grid = RECORD / "grid" / "dt0.02" / "nmp" / "points" / "s0"
    lines = (grid / "metrics.jsonl").read_text().splitlines()
    rows = [json.loads(line) for line in lines] + [{**json.loads(lines[-1]), "chunk": 17}]
    for s, change in (("s0", None), ("s1", 1.001)):
        src = RECORD / "grid" / "dt0.02" / "nmp" / "points" / s
        mine = [json.loads(line) for line in (src / "metrics.jsonl").read_text().splitlines()] if s != "s0" else rows
        mine = [{**r, "wall_s": r["wall_s"] + 1.0} for r in mine]
        if change:
            mine[4] = {**mine[4], "approx_kl": mine[4]["approx_kl"] * change}
        d = tmp_path / "amendment" / "dt0.02" / "nmp" / "points" / s
        d.mkdir(parents=True)
        (d / "config.json").write_text((src / "config.json").read_text())
        (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in mine))
    got = {r["point"]: r for r in am.continuation(tmp_path)}
    assert got["s0"]["identical"] and got["s0"]["max_rel_diff"] == 0.0 and got["s0"]["iterations"] == 16
    assert not got["s1"]["identical"] and got["s1"]["first_difference"] == "approx_kl at iteration 5"
    assert got["s1"]["max_rel_diff"] == pytest.approx(0.001 / 1.001)


def test_the_gaits_are_the_best_and_worst_2_5_ms_arms_median_runs():
    """Among W, Wc and NMp at 2.5 ms (NMp only when the rule runs it), the highest and the lowest
    cell mean; each arm's run is its lower median; nothing until every one of them has ended."""
    dets = {"white": [10, 40, 20, 30, 50, 60, 70, 80], "wc": [1, 2, 3, 4, 5, 6, 7, 8],
            "nmp": [100, 300, 200, 400, 500, 600, 700, 800]}
    rows = [_row(f"amendment/dt0.0025/{a}", s, v, 2.0) for a, vs in dets.items() for s, v in enumerate(vs)]
    walks = [_row("amendment/dt0.02/nmp", s, 100.0, 1.5) for s in range(8)]
    stands = [_row("amendment/dt0.02/nmp", s, 100.0, 0.2) for s in range(8)]
    assert am.gait_picks(rows) is None  # NMp(20) has not ended: whether NMp(2.5) runs is not known
    best, worst = am.gait_picks(rows + walks)
    assert (best["arm"], best["point"], best["cell_mean"]) == ("nmp", "s3", 450.0)  # 400: the lower of 400, 500
    assert (worst["arm"], worst["point"]) == ("wc", "s3")
    best, worst = am.gait_picks([r for r in rows if "nmp" not in r["cell"]] + stands)
    assert (best["arm"], best["point"]) == ("white", "s1") and worst["arm"] == "wc"  # 40: the lower of 40, 50
    assert am.gait_picks([r for r in rows if "/wc" not in r["cell"]] + walks) is None  # Wc(2.5) not run yet


def test_the_report_writes_its_tables_and_draws_once_cells_have_ended(tmp_path):
    rng = np.random.default_rng(4)
    rows = [_row(c, s, m + 30 * rng.standard_normal(), 2.0) for c, m in
            (("amendment/dt0.02/white", 100.0), ("amendment/dt0.02/nmp", 60.0)) for s in range(8)]
    am.report(rows, tmp_path)
    with open(tmp_path / am.CELLS_CSV, newline="") as fh:
        cells = {r["cell"]: r for r in csv.DictReader(fh)}
    white = np.array([float(r["det_reward_per_s"]) for r in rows if r["cell"] == "amendment/dt0.02/white"])
    assert float(cells["amendment/dt0.02/white"]["mean"]) == pytest.approx(white.mean())
    assert cells["amendment/dt0.02/white"]["walking"] == "8"
    assert (tmp_path / am.ENDPOINT_FIGURE).is_file() and (tmp_path / am.CONTRAST_FIGURE).is_file()  # A3 has its estimate
    assert (tmp_path / am.CONTINUATION_CSV).is_file() and not (tmp_path / am.LEARNING_FIGURE).exists()  # no points
