"""The first exploration study's publisher: results/exploration/ regenerated from its own record.

The study is finished; its record is the folder itself: the tables (``study.json``,
``results.csv``, ``control.csv``, ``screen.csv``, ``snr.csv``), every cell's runs under ``runs/``
(sweep.json, per point config.json, metrics.jsonl, compact.npz, ``eval/eval.json``: what continues a
cell with ``nmrl sweep --resume``) and the evaluated gaits under ``gaits/``. :func:`publish` makes
the rest from them, so that the published files follow from the committed data alone:

* ``summary.json``: the study's analysis of its rows (nmrl.analysis.exploration_answers.analysis),
  the screen's rule on the grid's first iterations and the control's learning curves by iteration
  from the runs' metrics, and the parts that record how the study ran (the control's design, the
  re-run commands);
* ``answers.md``: the tables of those numbers (nmrl.analysis.exploration_report) with the answers in
  words, which are prose and live in docs/exploration-study.md;
* ``learning_curves.png``, ``summary.png``, ``control.png`` (nmrl.analysis.exploration_figures) and
  ``gaits/best_and_worst.png`` where the two gaits' trajectories (``trajectory.npz``, not committed:
  ``nmrl eval`` writes them) are there.

    .venv/bin/python scripts/publish/publish_exploration.py [--dest results/exploration]
"""

from __future__ import annotations

import json
import pathlib
from typing import Sequence

from nmrl.analysis import exploration_answers as xa
from nmrl.analysis import exploration_figures, exploration_report
from nmrl.explore.spec import KINDS as PROCESSES
from nmrl.runs import store

ROOT = pathlib.Path(__file__).resolve().parents[2]
RECORD = ROOT / "results" / "exploration"
#: the page that holds the answers in words, between these two lines
WORDS_PAGE = ROOT / "docs" / "exploration-study.md"
WORDS_BEGIN, WORDS_END = "<!-- answers.md: the answers in words -->", "<!-- answers.md: end -->"


def words(page: pathlib.Path = WORDS_PAGE) -> list[str]:
    """The lines between :data:`WORDS_BEGIN` and :data:`WORDS_END` of ``page``."""
    lines = page.read_text(encoding="utf-8").split("\n")
    return lines[lines.index(WORDS_BEGIN) + 1:lines.index(WORDS_END)]


def _runs(record: pathlib.Path, phase: str, dt: float, process: str, seeds: int) -> list[list[dict]]:
    """The metrics rows of every seed of one cell that has any."""
    cell = record / "runs" / phase / f"dt{dt:g}" / process / "points"
    return [m for s in range(seeds) for m in [store.read_metrics(cell / f"s{s}")] if m]


def screen_from_grid(record: pathlib.Path, study: dict, results: Sequence[dict]) -> list[dict]:
    """The screen's rule (nmrl.analysis.exploration_answers.score) applied to the grid's runs at the
    screen's control step: the seeds the screen ran, their first iterations as many as the screen's
    runs had. `white` (the limit of every correlated process as its correlation shrinks) gets the
    score the screen has no run of; a chosen setting repeats its screen runs."""
    dt, n = study["screen_dt"], study["screen_iterations"]
    if dt not in study["dts"]:
        return []
    rows = []
    for p in PROCESSES:
        setting = next((r["setting"] for r in results if float(r["control_dt"]) == dt and r["exploration"] == p), "-")
        for s in range(min(study["screen_seeds"], study["seeds"])):
            m = store.read_metrics(record / "runs" / "grid" / f"dt{dt:g}" / p / "points" / f"s{s}")
            if len(m) >= n:
                rows.append({"exploration": p, "setting": setting, "seed": s, "score": xa.score(m[:n])})
    return rows


def summary(record: pathlib.Path) -> dict:
    """``summary.json`` of the record: the numbers made anew from its rows and runs; the design of
    the control and the re-run commands as recorded."""
    study = json.loads((record / "study.json").read_text())
    dts, iterations, seeds = tuple(study["dts"]), study["iterations"], study["seeds"]
    out = json.loads((record / "summary.json").read_text())
    results = store.read_csv(record / "results.csv")
    control = store.read_csv(record / "control.csv") if (record / "control.csv").exists() else []
    numbers = xa.analysis(results, control, store.read_csv(record / "screen.csv"), dts, PROCESSES, iterations)
    ctl = numbers.pop("control", None)
    out.update(numbers)
    out["screen_from_grid"] = screen_from_grid(record, study, results)
    if ctl is not None and out.get("control"):
        coarse, fine = max(dts), min(dts)
        out["control"].update(ctl)
        out["control"]["iterations"] = {
            "control": xa.iteration_means(_runs(record, "control", coarse, "white", seeds)),
            "white_fine": xa.iteration_means(_runs(record, "grid", fine, "white", seeds)),
            "white_coarse": xa.iteration_means(_runs(record, "grid", coarse, "white", seeds))}
    return out


def publish(record: pathlib.Path = RECORD, dest: pathlib.Path | None = None,
            said: Sequence[str] | None = None) -> list[pathlib.Path]:
    """Write summary.json, answers.md and the figures of ``record`` into ``dest`` (default: the
    record itself); ``said``: the answers in words (default: :func:`words`). Returns the files."""
    record = pathlib.Path(record)
    dest = record if dest is None else pathlib.Path(dest)
    study = json.loads((record / "study.json").read_text())
    dts, iterations = tuple(study["dts"]), study["iterations"]
    rows = store.read_csv(record / "results.csv")
    snr = store.read_csv(record / "snr.csv") if (record / "snr.csv").exists() else []
    screen = store.read_csv(record / "screen.csv")
    s = summary(record)
    dest.mkdir(parents=True, exist_ok=True)
    written = [dest / "summary.json", dest / "answers.md"]
    store.atomic_write_json(written[0], s)
    store.atomic_write_text(written[1], exploration_report.report(
        s, rows, screen, snr, dts, PROCESSES, iterations, words() if said is None else said))
    written.append(exploration_figures.draw(record / "runs", rows, dts, PROCESSES, dest / "learning_curves.png"))
    written.append(exploration_figures.draw_summary(rows, snr, dts, PROCESSES, iterations, dest / "summary.png"))
    if s.get("control"):
        written.append(exploration_figures.draw_control(s["control"], dest / "control.png"))
    fine = min(dts)
    done = [r for r in xa.finished(rows, iterations) if float(r["control_dt"]) == fine]
    picks = xa.best_and_worst(done, fine, PROCESSES) if len(done) == study["seeds"] * len(PROCESSES) else None
    gaits = [(f"{rank} at δ = {fine * 1000:g} ms: {proc} (its median seed, {seed}; deterministic policy)",
              record / "gaits" / proc / "trajectory.npz") for (proc, seed), rank in zip(picks or [], ("best", "worst"))]
    if gaits and all(f.exists() for _, f in gaits):
        written.append(exploration_figures.draw_gaits(gaits, dest / "gaits" / "best_and_worst.png"))
    return written

