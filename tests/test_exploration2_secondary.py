"""The second exploration study's secondary family and checks in its published record.

Once the secondary family's cells have all ended, ``analysis.csv``'s S1-S7 and the doc's table of
them are what scipy, Holm's procedure and a contrast of 4 cells by hand give from the committed
rows.csv (tests/test_exploration2_record.py's ``_family``); before, S1-S7 read "pending". The checks
that decide nothing (W's sigma sensitivity at 2.5 ms, the asymptote at 5 ms) are scipy's Welch
intervals of their cells, the asymptote's arm the best correlated 2.5 ms grid cell by rows.csv; the
doc's verdict on the comparator is the registered rule applied to the rows (the asymptote's own
checks: tests/test_exploration2_asymptote.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from nmrl.experiments import kit
from tests.doc_numbers import assert_numbers, normalised, table_row
from tests.test_exploration2_record import (DOC, GRID, LATER, RECORD, _assert_docs_table_is, _assert_table_is, _csv,
                                            _doc, _family, _finished, _interaction, _n, _p, _welch)

pytestmark = pytest.mark.skipif(not (RECORD / kit.ROWS).is_file(), reason="no published record of study 2")

CELLS = {**GRID, **LATER}
#: the secondary family's 20 ms cells (4 seeds each; their means are checked with LATER's)
LATER20 = ("OU(20)", "CN(20)", "NMs(20)")

#: the secondary family as the doc's Progress ("Written before any grid cell ran") writes it
SECONDARY = (("S1", {"W(5)": 1, "W(20)": -1}), ("S2", {"Ws(5)": 1, "W(5)": -1}), ("S3", {"NMp(5)": 1, "W(5)": -1}),
             ("S4", {"NMp(5)": 1, "NMp(20)": -1, "W(5)": -1, "W(20)": 1}),
             *((f"S{5 + i}", {f"{x}(2.5)": 1, f"{x}(20)": -1, "W(2.5)": -1, "W(20)": 1})
               for i, x in enumerate(("OU", "CN", "NMs"))))


def _cells() -> dict[str, np.ndarray] | None:
    """The secondary family's cells' deterministic endpoints, or None while one has not ended."""
    cells = {name: _finished(CELLS[name]) for _, weights in SECONDARY for name in weights}
    return None if any(x is None for x in cells.values()) else cells


def test_the_secondary_familys_decisions_are_holm_over_welch_and_tost_of_the_rows():
    """analysis.csv's every number and word for S1-S7 is :func:`_family` of rows.csv once the family's
    cells have ended; before, every decision reads "pending"."""
    table = {r["contrast"]: r for r in _csv(RECORD / kit.ANALYSIS) if r["family"] == "secondary"}
    assert sorted(table) == [label for label, _ in SECONDARY]
    cells = _cells()
    if cells is None:
        assert {r["decision"] for r in table.values()} == {"pending"}
        pytest.skip("the secondary family's cells have not all ended in the record")
    _assert_table_is(table, _family(cells, SECONDARY))


def test_the_docs_table_of_the_secondary_family_is_holm_over_welch_and_tost_of_the_rows():
    """The Results' table of S1-S7 (as P1-P7's: estimate [95% interval], raw p, Holm p, TOST p with its
    Holm p, the decision) is :func:`_family` of the rows, once the family's cells have ended."""
    cells = _cells()
    if cells is None:
        pytest.skip("the secondary family's cells have not all ended in the record")
    _assert_docs_table_is(_family(cells, SECONDARY))


def _rows_of(cell: str) -> list[dict]:
    return [r for r in _csv(RECORD / kit.ROWS) if r["cell"] == cell]


def test_the_checks_are_welch_intervals_of_their_ended_cells():
    """analysis.csv's checks: a sensitivity row for each of W's neighbouring-sigma cells at 2.5 ms whose
    4 runs have ended (that cell minus the grid's W(2.5)), and the asymptote (the best correlated arm
    at 2.5 ms by rows.csv's means, minus white, both at 5 ms and 64 iterations), each scipy's Welch
    interval of its cells once they have ended, "pending" before."""
    checks = {r["contrast"]: r for r in _csv(RECORD / kit.ANALYSIS) if r["family"] == "check"}
    cells = {r["cell"] for r in _csv(RECORD / kit.ROWS)}
    want = {}
    for cell in sorted(c for c in cells if c.startswith("sensitivity/dt0.0025/white_sigma")):
        if _finished(cell) is not None:
            want[cell.split("/")[-1]] = (cell, GRID["W(2.5)"])
    means = {arm: _finished(GRID[name]).mean() for arm, name in
             (("ou", "OU(2.5)"), ("colored", "CN(2.5)"), ("nms", "NMs(2.5)"), ("nmp", "NMp(2.5)"))}
    best = max(means, key=means.get)
    want["asymptote"] = (f"asymptote/dt0.005/{best}", "asymptote/dt0.005/white")
    assert set(checks) == set(want)
    for label, (a, b) in want.items():
        row = checks[label]
        assert row["cells"] == f"+1*{a} -1*{b}", label
        xa, xb = _finished(a), _finished(b)
        if xa is None or xb is None:
            assert row["decision"] == "pending", label
            continue
        assert [len(_rows_of(a)), len(_rows_of(b))] == [4, 8 if b in GRID.values() else 4]
        assert row["decision"] == "reported"
        got = [float(row[k]) for k in ("estimate", "lo", "hi", "p")]
        assert got == pytest.approx(_welch(xa, xb), rel=1e-9), label


def _readme() -> str:
    """The README with its whitespace runs made single spaces."""
    return " ".join((DOC.parents[1] / "README.md").read_text().split())


SENSITIVITY = ("0.4", "2.5")


def _sensitivity() -> dict[str, np.ndarray] | None:
    """W's sigma sensitivity cells' deterministic endpoints by sigma, or None while one has not ended."""
    cells = {x: _finished(LATER[f"W(2.5) σ {x}"]) for x in SENSITIVITY}
    return None if any(x is None for x in cells.values()) else cells


def test_the_docs_table_of_the_comparators_sigma_is_welch_of_the_rows():
    """The Results' table of W's sigma sensitivity: per sigma its cell's mean (SD), and the cell minus
    the grid's W(2.5) with scipy's Welch 95% interval and raw p, once both cells have ended."""
    cells = _sensitivity()
    if cells is None:
        pytest.skip("W's sigma sensitivity has not ended in the record")
    w = _finished(GRID["W(2.5)"])
    doc = _doc()
    grid = next(line for line in doc.splitlines() if line.startswith("| 1 "))
    assert_numbers(grid.split("|", 2)[2], [_n(w.mean()), _n(w.std(ddof=1))], window=20)
    for sigma, x in cells.items():
        e, lo, hi, p = _welch(x, w)
        row = table_row(doc, sigma)
        assert_numbers(" | ".join(row[1:]), [_n(x.mean()), _n(x.std(ddof=1)), _n(e), _n(lo), _n(hi), _p(p)])


def test_the_verdict_on_the_comparator_is_the_registered_rule():
    """The registered rule: if a neighbouring sigma's cell beats the grid's W(2.5) by more than 50
    reward per s (its estimate), P2-P6 are conditional on an untuned comparator. From the rows no
    neighbour does (the verdict the Results give): the estimates are below the margin."""
    cells = _sensitivity()
    if cells is None:
        pytest.skip("W's sigma sensitivity has not ended in the record")
    w = _finished(GRID["W(2.5)"]).mean()
    assert max(x.mean() - w for x in cells.values()) <= 50


#: the doc's observed interactions of the secondary family, each "estimate [95% interval] (raw p ...)"
INTERACTION_CLAIMS = ("S4", "S5", "S6")


@pytest.mark.parametrize("label", INTERACTION_CLAIMS)
def test_the_docs_observed_interactions_are_contrasts_of_4_cells_by_hand(label):
    weights = dict(SECONDARY)[label]
    xs = [(w, _finished(CELLS[name])) for name, w in weights.items()]
    if any(x is None for _, x in xs):
        pytest.skip(f"{label}: a cell has not finished in the record")
    e, lo, hi, p, _ = _interaction(xs)
    assert_numbers(_doc(), [_n(e), _n(lo), _n(hi), _p(p)], label=f"{label}, [", window=120)


#: the Progress bullets of the later cells, by their title, with the speeds they give
BULLETS = (("W at 5 ms", "W(5)"), ("Ws at 5 ms", "Ws(5)"), ("NMp at 5 ms", "NMp(5)"), ("OU at 20 ms", "OU(20)"),
           ("CN at 20 ms", "CN(20)"), ("NMs at 20 ms", "NMs(20)"), ("W at 2.5 ms with σ = 0.4", "W(2.5) σ 0.4"),
           ("W at 2.5 ms with σ = 2.5", "W(2.5) σ 2.5"), ("W at 5 ms with 4× the budget", "W(5) 64 it"),
           ("CN at 5 ms with 4× the budget", "CN(5) 64 it"))


#: the later cells whose bullet gives the speed with a quarter of the noise (noise_scales.csv at k = 0.25)
QUARTER_NOISE = ("NMp(5)",)


@pytest.mark.parametrize("title,name", BULLETS, ids=[b[1] for b in BULLETS])
def test_the_docs_speeds_of_a_later_cell_are_its_runs(title, name):
    """A later cell's Progress bullet gives the range over its runs of the deterministic policy's
    forward speed and of the exploring policy's over the last iteration (rows.csv), and where it
    names one, of the speed with a quarter of the noise (noise_scales.csv at k = 0.25)."""
    if _finished(CELLS[name]) is None:
        pytest.skip(f"{name} has not finished in the record")
    bullet = normalised(_doc()).split(f"* {title} finished", 1)[1].split(" * ", 1)[0]
    for key in ("det_forward_speed", "forward_speed"):
        x = _finished(CELLS[name], key)
        assert_numbers(bullet, [f"{x.min():.2f}", f"{x.max():.2f}"], window=8)
    if name in QUARTER_NOISE:
        x = [float(r["forward_speed"]) for r in _csv(RECORD / "noise_scales.csv")
             if r["cell"] == CELLS[name] and float(r["noise_scale"]) == 0.25]
        assert len(x) == 4
        assert_numbers(bullet, [f"{min(x):.2f}", f"{max(x):.2f}"], window=8)


def test_the_docs_means_of_the_20_ms_sigma_screens_are_the_rows():
    """The screens of OU, CN and NMs at 20 ms: each sigma's mean deterministic reward per second over
    the screen's two seeds (rows.csv), in the doc's order of sigma and arms."""
    rows = _csv(RECORD / kit.ROWS)
    parts = []
    for arm, name in (("ou", "OU"), ("colored", "CN"), ("nms", "NMs")):
        by: dict[float, list[float]] = {}
        for r in rows:
            if r["cell"] == f"screen/sigma/dt0.02/{arm}":
                by.setdefault(float(r["value"]), []).append(float(r["det_reward_per_s"]))
        if sorted(by) != [0.064, 0.16, 0.4, 1.0] or any(len(x) != 2 for x in by.values()):
            pytest.skip(f"the 20 ms sigma screen of {name} has not ended in the record")
        parts += [_n(np.mean(by[v])) for v in sorted(by)]
    assert_numbers(_doc(), parts, window=160)


@pytest.mark.parametrize("name", LATER20)
def test_the_docs_noise_scale_means_of_the_20_ms_cells_are_the_table(name):
    """The mean reward per second of the cell's policies with their noise times k = 0, 0.25, 0.5, 1
    (noise_scales.csv, all 4 runs at each k)."""
    if _finished(CELLS[name]) is None:
        pytest.skip(f"{name} has not finished in the record")
    got = [r for r in _csv(RECORD / "noise_scales.csv") if r["cell"] == CELLS[name]]
    means = []
    for k in (0.0, 0.25, 0.5, 1.0):
        x = [float(r["reward_per_s"]) for r in got if float(r["noise_scale"]) == k]
        assert len(x) == 4, (name, k)
        means.append(np.mean(x))
    assert_numbers(_doc(), [_n(m) for m in means], window=40)


def test_the_docs_new_cells_of_the_decided_secondary_family_are_the_rows():
    """The Results' line of the secondary family's six 4-seed cells: each mean and SD from rows.csv."""
    cells = _cells()
    if cells is None:
        pytest.skip("the secondary family's cells have not all ended in the record")
    new = ("W(5)", "Ws(5)", "NMp(5)", "OU(20)", "CN(20)", "NMs(20)")
    assert all(len(cells[name]) == 4 for name in new)
    assert_numbers(_doc(), [x for name in new for x in (_n(cells[name].mean()), _n(cells[name].std(ddof=1)))],
                   label=f"{new[0]} ", window=200)


def test_the_secondary_family_decides_as_the_primary_at_5_ms():
    """At 5 ms the secondary family decides as the primary does at 2.5 ms: white ahead of its 20 ms
    cell (S1, as P1), NMp behind white and losing more than white from 20 ms (S3, S4, as P6, P7),
    eq. (1)'s scaled white not detected against white (S2, as P2)."""
    cells = _cells()
    if cells is None:
        pytest.skip("the secondary family's cells have not all ended in the record")
    got = {label: r["decision"] for label, r in _family(cells, SECONDARY).items()}
    assert [got[s] for s in ("S1", "S2", "S3", "S4")] == ["ahead", "not detected", "behind", "behind"]
