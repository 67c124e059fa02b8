"""Each grid policy with its noise scaled (nmrl/experiments/exploration2_noise.py), on published 20 ms
policies: which runs it measures, that k = 0 is the deterministic endpoint (the one the study published
for the run, within its sampling error on another processor), that a run is measured once per saved step,
and the figure from its table."""

from __future__ import annotations

import json
import pathlib
import shutil

import pytest

from nmrl.analysis import endpoint
from nmrl.experiments import exploration2_noise as xn
from nmrl.experiments.exploration2_cells import ARM_COLORS
from nmrl.runs import checkpoint, store
from tests.endpoint_rounding import assert_same_endpoint

REPO = pathlib.Path(__file__).resolve().parents[1]
RUNS = REPO / "results/exploration2/runs"
POINTS = {"grid/dt0.02/white": "s0", "grid/dt0.02/nmp": "s0"}


def _row(cell: str, point: str, steps: int, budget: int, det: float | str = -40.0) -> dict:
    return {"cell": cell, "point": point, "seed": int(point[1:]), "steps": steps, "budget": budget,
            "diverged": "False", "det_reward_per_s": det}


def test_every_ended_run_of_a_complete_grid_cell_at_every_noise_scale_once_per_step(tmp_path, monkeypatch,
                                                                                     saved_figures):
    if not all((RUNS / c / "points" / p / "compact.npz").is_file() for c, p in POINTS.items()):
        pytest.skip("the published 20 ms grid points are not in this checkout")
    rows = []
    for cell, point in POINTS.items():
        shutil.copytree(RUNS / cell / "points" / point, tmp_path / cell / "points" / point)
        step = json.loads((RUNS / cell / "points" / point / "endpoint.json").read_text())["step"]
        rows.append(_row(cell, point, step, step))
    # a cell with a run still going is not measured; neither is a screen cell
    rows += [_row("grid/dt0.0025/ou", "s0", 5, 10, det=""), _row("grid/dt0.0025/ou", "s1", 10, 10),
             _row("screen/sigma/dt0.02/white", "s9", 10, 10)]
    xn.noise_scales(tmp_path, rows)
    got = store.read_csv(tmp_path / xn.NOISE_CSV)
    assert sorted((r["cell"], r["point"], r["noise_scale"]) for r in got) == sorted(
        (c, p, k) for c, p in POINTS.items() for k in xn.NOISE_SCALES)
    for cell, point in POINTS.items():
        published = json.loads((RUNS / cell / "points" / point / "endpoint.json").read_text())
        mine = {r["noise_scale"]: r for r in got if r["cell"] == cell}
        _, config, params = checkpoint.restore_params(RUNS / cell / "points" / point, published["step"])
        here = endpoint.deterministic_endpoint(config, params, seconds=10.0, rollouts=8, start_noise=0.05, seed=0)
        assert mine[0.0]["reward_per_s"] == here["reward_per_s"]  # k = 0 is the deterministic endpoint
        assert mine[0.0]["forward_speed"] == pytest.approx(sum(here["forward_speed"]) / 8, rel=1e-12)
        # ... which is the one the study published (exact on the publishing processor; tests/endpoint_rounding.py)
        assert_same_endpoint(here["rollouts"], published["reward_per_s"], published["rollouts"], label=cell)
        assert {r["step"] for r in mine.values()} == {published["step"]}
        assert len({r["reward_per_s"] for r in mine.values()}) == len(xn.NOISE_SCALES)  # k moves the result

    def refuse(*_a, **_k):
        raise AssertionError("measured again")

    monkeypatch.setattr(endpoint, "noisy_endpoint", refuse)
    monkeypatch.setattr(checkpoint, "restore_params", refuse)
    xn.noise_scales(tmp_path, rows)  # nothing new: no policy restored, nothing measured, the table unchanged
    assert store.read_csv(tmp_path / xn.NOISE_CSV) == got
    xn.figure(tmp_path)
    ((path, fig),) = saved_figures
    assert path == tmp_path / xn.NOISE_FIGURE and path.stat().st_size > 10_000
    reward, speed = fig.axes  # one column, 20 ms: reward per second above forward speed
    for ax, column in ((reward, "reward_per_s"), (speed, "forward_speed")):
        for cell in POINTS:
            arm = cell.rsplit("/", 1)[1]
            (line,) = [ln for ln in ax.lines if ln.get_label() == f"{arm} (1)"]
            mine = sorted((float(r["noise_scale"]), float(r[column])) for r in got if r["cell"] == cell)
            assert list(line.get_xdata()) == [k for k, _ in mine] == sorted(xn.NOISE_SCALES)
            assert list(line.get_ydata()) == [v for _, v in mine]  # one run: its values are the mean
            assert line.get_color() == ARM_COLORS[arm]
