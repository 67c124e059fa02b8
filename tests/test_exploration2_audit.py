"""Study 2's audit: the numbers that say what the family does not test, recomputed from the committed
record (rows.csv and the grid runs' metrics.jsonl) with NumPy, independently of the study's analysis."""
from __future__ import annotations

import csv
import json
import pathlib

import numpy as np
import pytest

from tests.doc_numbers import assert_numbers
from tests.endpoint_rounding import assert_same_endpoint

REPO = pathlib.Path(__file__).resolve().parents[1]
RECORD = REPO / "results" / "exploration2" / "runs"

pytestmark = pytest.mark.skipif(not (RECORD / "rows.csv").is_file(), reason="no published record of study 2")


def _pages() -> tuple[str, str]:
    return (REPO / "README.md").read_text(), (REPO / "docs" / "exploration-study-2.md").read_text()


def _rows(cell: str) -> list[dict]:
    with open(RECORD / "rows.csv", newline="") as fh:
        return [r for r in csv.DictReader(fh) if r["cell"] == cell]


def _col(cell: str, key: str) -> np.ndarray:
    return np.array([float(r[key]) for r in _rows(cell)])


def _n(x: float, digits: int = 1) -> str:
    return f"{x:.{digits}f}".replace("-", "\N{MINUS SIGN}")


def test_nmp_stands_at_every_control_step_in_every_run():
    """Every NMp run's deterministic policy stands (forward speed under 0.2 m/s) at 20, 5 and 2.5 ms,
    while white's cells walk; the pages' range of speeds and the cells' means are the rows'."""
    readme, doc = _pages()
    speeds = np.concatenate([_col(f"grid/dt{dt}/nmp", "det_forward_speed") for dt in ("0.02", "0.005", "0.0025")])
    assert speeds.max() < 0.2
    for page in (readme, doc):
        assert_numbers(page, [f"{speeds.min():.2f}", f"{speeds.max():.2f}"], window=8)
    for dt in ("0.02", "0.005", "0.0025"):
        assert _col(f"grid/dt{dt}/white", "det_forward_speed").mean() > 1.0
        nmp = _n(_col(f"grid/dt{dt}/nmp", "det_reward_per_s").mean())
        assert_numbers(readme, [nmp])
        assert_numbers(doc, [nmp])


def test_the_floor_effect_is_the_cells_change_from_20_to_2_5_ms():
    readme, _ = _pages()
    nmp = _col("grid/dt0.0025/nmp", "det_reward_per_s").mean() - _col("grid/dt0.02/nmp", "det_reward_per_s").mean()
    white = _col("grid/dt0.0025/white", "det_reward_per_s").mean() - _col("grid/dt0.02/white", "det_reward_per_s").mean()
    assert_numbers(readme, [_n(nmp), _n(white)], window=40)


def test_the_screen_did_not_rank_whites_sigma_that_the_full_budget_separates():
    """W(2.5) at σ 0.4 and 1: their screen means (4 iterations, 2 seeds) are within a fraction of a
    reward per second, their full-budget means ~200 apart; no screen run walked."""
    readme, doc = _pages()
    screen = {s: _col("screen/sigma/dt0.0025/white", "det_reward_per_s")[
        [r["value"] == s for r in _rows("screen/sigma/dt0.0025/white")]].mean() for s in ("0.4", "1.0")}
    full = {"0.4": _col("sensitivity/dt0.0025/white_sigma0.4", "det_reward_per_s").mean(),
            "1.0": _col("grid/dt0.0025/white", "det_reward_per_s").mean()}
    gap_screen, gap_full = abs(screen["1.0"] - screen["0.4"]), full["1.0"] - full["0.4"]
    assert gap_screen < 1 and gap_full > 100
    for page in (readme, doc):
        assert_numbers(page, [f"{gap_screen:.2f}"])
        assert_numbers(page, [_n(gap_full)])
    with open(RECORD / "rows.csv", newline="") as fh:
        screen_rows = [r for r in csv.DictReader(fh) if r["cell"].startswith("screen/")]
    assert max(float(r["det_forward_speed"]) for r in screen_rows) < 0.08
    assert_numbers(doc, [f"{min(float(r['det_reward_per_s']) for r in screen_rows):.0f}"])


def _median_kl_per_step(cell: str) -> float:
    """The median of PPO's logged approximate KL per control step over iterations 2-16 and every seed
    (the first iteration, where the observation normaliser first moves, left out)."""
    kl = []
    for path in sorted((RECORD / "grid" / cell / "points").glob("*/metrics.jsonl")):
        lines = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        kl += [line["approx_kl"] for line in lines[1:]]
    assert len(kl) >= 4 * 15
    return float(np.median(kl))


def test_whites_trust_region_per_second_widens_at_the_fine_step():
    """The KL per second of behaviour is the KL per control step over δ (a product of per-step
    policies); the pages' per-step and per-second numbers are the logs'."""
    readme, doc = _pages()
    per_step = {dt: _median_kl_per_step(f"dt{dt}/white") for dt in ("0.02", "0.005", "0.0025")}
    per_s = {dt: kl / float(dt) for dt, kl in per_step.items()}
    assert per_s["0.0025"] > 3 * per_s["0.02"]
    for dt in per_step:
        assert_numbers(doc, [f"{per_step[dt]:.3f}", f"{per_s[dt]:.1f}"], window=60)
    for dt in ("0.02", "0.0025"):
        assert_numbers(readme, [f"{per_step[dt]:.3f}", f"{per_s[dt]:.1f}"], window=60)


def test_the_trust_region_table_is_the_grid_logs_per_second_of_behaviour():
    """trust_region.csv (nmrl/experiments/exploration2_diagnosis.py) recomputed: per cell and
    iteration the median over seeds of the clipped share and of the KL per ratio over the seconds a
    ratio covers (NMp: its period, 0.06 s at 20 ms and 0.02 s at 2.5 ms; white: the control step)."""
    path = RECORD / "trust_region.csv"
    with open(path, newline="") as fh:
        table = list(csv.DictReader(fh))
    for cell, per in (("dt0.02/white", 0.02), ("dt0.02/nmp", 0.06), ("dt0.0025/white", 0.0025), ("dt0.0025/nmp", 0.02)):
        logs = [[json.loads(x) for x in p.read_text().splitlines() if x.strip()]
                for p in sorted((RECORD / "grid" / cell / "points").glob("*/metrics.jsonl"))]
        rows = [r for r in table if r["cell"] == f"grid/{cell}"]
        assert len(rows) == 16
        for r in rows:
            it = int(r["iteration"]) - 1
            assert float(r["clip_frac"]) == pytest.approx(np.median([m[it]["clip_frac"] for m in logs]))
            assert float(r["kl_per_s"]) == pytest.approx(np.median([m[it]["approx_kl"] for m in logs]) / per)


def test_the_diagnosis_tables_endpoints_are_the_published_runs():
    """The NMp variants' deterministic endpoints and speeds in the study page are the published
    diagnosis rows' (results/exploration2/diagnosis/rows.csv), and none of them walks (< 1 m/s)."""
    _, doc = _pages()
    with open(RECORD.parent / "diagnosis" / "rows.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 10
    for variant in ("nmp_sigma0.4", "nmp_sigma0.16", "nmp_sigma1_fixed_std", "nmp_sigma1_clip0.52",
                    "nmp_sigma1_corr0.01"):
        rs = sorted((r for r in rows if r["cell"] == f"dt0.02/{variant}"), key=lambda r: int(r["seed"]))
        assert_numbers(doc, [f"{float(r['det_reward_per_s']):.1f}" for r in rs], window=12)
        assert all(float(r["det_forward_speed"]) < 1.0 for r in rs)


def test_the_diagnosis_trust_region_and_noise_scales_are_the_published_runs():
    """The variants' KL per second and clipped share (medians over iterations 2-16 of the medians over
    seeds, from the published metrics.jsonl) and their forward speeds with the noise times k (the
    published noise_scales.csv) are the page's; every variant's mean stands while its noise moves it."""
    from nmrl.experiments import exploration2_diagnosis as diag

    _, doc = _pages()
    root = RECORD.parent / "diagnosis"
    cells = ("dt0.02/nmp_sigma1_clip0.52", "dt0.02/nmp_sigma1_corr0.01")
    summary = diag.summary(diag.trust_region(root, cells))
    for cell in cells:
        kl, clip = summary[cell]["kl_per_s"], summary[cell]["clip_frac"]
        assert_numbers(doc, [f"{kl:.2f}", f"{clip:.3f}"], window=12)
    with open(root / "noise_scales.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    for cell in cells:
        speeds = [np.mean([float(r["forward_speed"]) for r in rows if r["cell"] == cell and float(r["noise_scale"]) == k])
                  for k in (0.0, 0.25, 0.5, 1.0)]
        assert_numbers(doc, [f"{v:.2f}" for v in speeds], window=24)
        assert speeds[0] < 0.5 and speeds[-1] > 1.0  # stands alone, moves with its noise


def test_the_grids_noise_scales_quoted_beside_the_diagnosis_are_the_record():
    """NMp(20)'s and white's mean forward speeds at k = 0, 0.25, 0.5, 1 (study 2's noise_scales.csv)."""
    _, doc = _pages()
    with open(RECORD / "noise_scales.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    for cell in ("grid/dt0.02/nmp", "grid/dt0.02/white"):
        speeds = [np.mean([float(r["forward_speed"]) for r in rows if r["cell"] == cell and float(r["noise_scale"]) == k])
                  for k in (0.0, 0.25, 0.5, 1.0)]
        assert_numbers(doc, [f"{v:.2f}" for v in speeds], window=24)


STAGES = RECORD.parent / "diagnosis" / "stages"


def _stages() -> list[dict]:
    with open(STAGES / "stages.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_the_stages_training_speeds_are_the_runs_metrics_and_the_page_quotes_every_stage():
    """stages.csv's training speed at each stage is the published run's metrics.jsonl at that step
    (iteration x 5,120 control steps at 20 ms); the study page's table row of each stage holds the
    three speeds of both seeds of each arm, to two decimals."""
    _, doc = _pages()
    rows = _stages()
    assert {(r["arm"], r["point"]) for r in rows} == {(a, p) for a in ("white", "nmp") for p in ("s0", "s1")}
    for r in rows:
        log = [json.loads(x) for x in (STAGES / "dt0.02" / r["arm"] / "points" / r["point"] / "metrics.jsonl")
               .read_text().splitlines() if x.strip()]
        step = int(r["iteration"]) * 5120
        assert int(r["step"]) == step
        assert float(r["train_forward_speed"]) == pytest.approx(next(m["forward_speed"] for m in log if m["step"] == step))
    quoted = {(8, "white"), (12, "white"), (14, "white"), (16, "white"), (8, "nmp"), (12, "nmp"), (16, "nmp"),
              (20, "nmp"), (24, "nmp"), (28, "nmp"), (32, "nmp")}
    for it, arm in quoted:
        pair = sorted((r for r in rows if r["arm"] == arm and int(r["iteration"]) == it), key=lambda r: r["point"])
        for key in ("train_forward_speed", "det_forward_speed", "noisy_forward_speed"):
            cell = [f"{abs(float(r[key])):.2f}" if abs(float(r[key])) < 0.005 else f"{float(r[key]):.2f}" for r in pair]
            assert_numbers(doc, cell, window=8)


def test_the_stages_show_each_mean_walking_last_and_nmp_at_half_the_pace():
    """The claims the page and README draw from stages.csv: white's mean stands (< 0.35 m/s) at
    iterations 10-14 while its exploring policy trains at >= 1 m/s, and walks (>= 1 m/s) in one seed
    at 16; NMp's mean stands at 16-28 and walks in one seed at 32, when its exploring policy trains
    faster than white's did at 16."""
    rows = _stages()

    def at(arm, it, key):
        return [float(r[key]) for r in sorted(rows, key=lambda r: r["point"]) if r["arm"] == arm and int(r["iteration"]) == it]

    for it in (10, 12, 14):
        assert max(at("white", it, "det_forward_speed")) < 0.35 and min(at("white", it, "train_forward_speed")) >= 1.0
    assert sum(v >= 1.0 for v in at("white", 16, "det_forward_speed")) == 1
    for it in (16, 20, 24, 28):
        assert max(at("nmp", it, "det_forward_speed")) < 0.3
    assert sum(v >= 1.0 for v in at("nmp", 32, "det_forward_speed")) == 1
    assert min(at("nmp", 28, "train_forward_speed")) > max(at("white", 16, "train_forward_speed"))
    assert min(at("nmp", 32, "noisy_forward_speed")) > max(at("white", 16, "noisy_forward_speed"))


def test_the_last_stages_deterministic_endpoint_recomputes_from_the_published_state():
    """NMp seed 1's deterministic endpoint after 32 iterations, recomputed from its published compact
    state with the study's endpoint (8 rollouts of 10 s from perturbed starts), is stages.csv's, within
    the endpoint's sampling error where this processor's float32 rounding differs from the publisher's."""
    from nmrl.analysis import endpoint
    from nmrl.runs import checkpoint

    row = next(r for r in _stages() if r["arm"] == "nmp" and r["point"] == "s1" and r["iteration"] == "32")
    meta, config, params = checkpoint.restore_params(STAGES / "dt0.02" / "nmp" / "points" / "s1")
    assert int(meta["step"]) == int(row["step"])
    e = endpoint.deterministic_endpoint(config, params, seconds=10.0, rollouts=8, start_noise=0.05, seed=0)
    # exact on the processor that published it; elsewhere within its sampling error (tests/endpoint_rounding.py)
    assert_same_endpoint(e["rollouts"], float(row["det_reward_per_s"]), label="reward per second")
    assert_same_endpoint(e["forward_speed"], float(row["det_forward_speed"]), label="forward speed")


def test_the_policy_shape_ranges_quoted_are_the_published_table():
    """policy_shape.csv (scripts/lab/policy_shape.py over the grid's 20 ms white and NMp policies):
    the page's ranges of the noise scale's variation over time, the mean action's and the noise's
    standard deviations are the table's, and no policy's noise scale varies by more than 0.15 of its
    mean along its gait."""
    _, doc = _pages()
    with open(RECORD.parent / "diagnosis" / "policy_shape.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    for arm in ("nmp", "white"):
        rs = [r for r in rows if r["cell"].endswith(f"/{arm}")]
        assert len(rs) == 8
        for key in ("std_cv", "mean_action_sd", "noise_action_sd"):
            v = [float(r[key]) for r in rs]
            assert_numbers(doc, [f"{min(v):.2f}", f"{max(v):.2f}"], window=8)
        assert max(float(r["std_cv"]) for r in rs) < 0.15
