"""Where a study's cells stand and the wall time they have left, read from their files alone.

Safe beside a running study (nmrl/experiments/kit.py): it reads each point's ``metrics.jsonl``, whose
rows carry the saved step and the chunk's wall seconds (compiles apart), and writes nothing. A cell's
time left is priced at its recent pace, the median of its last :data:`RECENT` chunks: a study shares
the cores with other work at times, so its pace changes, and its whole history's mean would price
the chunks left at the load of sessions long gone.
"""

from __future__ import annotations

import pathlib

import numpy as np

from nmrl.experiments.kit import Study, all_cells, point_dirs
from nmrl.runs import store

PROGRESS_COLUMNS = ("cell", "points", "steps", "budget", "chunks", "s_per_chunk", "remaining_s")
#: the chunks whose median wall time is a cell's recent pace
RECENT = 10


def progress(study: Study, out: pathlib.Path) -> list[dict]:
    """Where each cell known so far stands, read from its files alone (safe beside a running study):
    its points, the steps its least advanced point has saved (0 before its first saved chunk; a
    diverged point counts as done), the budget, the chunks run, the median wall seconds of its last
    :data:`RECENT` chunks (``wall_s`` in metrics.jsonl, compiles apart; from a point that has saved
    one) and the wall seconds its remaining chunks take at that pace. A cell without points has only
    its budget; none of its numbers is guessed."""
    res = []
    for cell in all_cells(study, out):
        limit = cell.budget_limit()
        budget = limit[1] if limit is not None and limit[0] == "step" else None
        row = dict.fromkeys(PROGRESS_COLUMNS, "")
        row.update(cell=cell.name, budget=budget if budget is not None else "")
        ms = [store.read_metrics(p) for p in point_dirs(out / cell.name)]
        if ms:
            open_ = [m for m in ms if not any(store.is_diverged(r) for r in m)]
            slowest = min(open_, key=_saved_step) if open_ else ms[0]
            steps = _saved_step(slowest) if open_ else budget
            row.update(points=len(ms), steps=steps, chunks=len(slowest))
            timed = slowest or next((m for m in ms if m), [])
            if timed:
                per_chunk = timed[0]["step"]
                wall = float(np.median([r["wall_s"] for r in timed[-RECENT:]]))
                row["s_per_chunk"] = round(wall, 1)
                if budget is not None and per_chunk > 0:
                    row["remaining_s"] = round(max(0, -(-(budget - steps) // per_chunk)) * wall)
        res.append(row)
    return res


def _saved_step(metrics: list[dict]) -> int:
    return metrics[-1]["step"] if metrics else 0


def progress_text(rows: list[dict]) -> str:
    """:func:`progress`'s rows as an aligned table, with the wall time left in the started cells and
    the count of cells not started below it."""
    table = [PROGRESS_COLUMNS, *([str(r[c]) for c in PROGRESS_COLUMNS] for r in rows)]
    widths = [max(len(t[i]) for t in table) for i in range(len(PROGRESS_COLUMNS))]
    lines = ["  ".join(x.ljust(w) for x, w in zip(t, widths)).rstrip() for t in table]
    left = sum(r["remaining_s"] for r in rows if r["remaining_s"] != "")
    waiting = sum(r["steps"] == "" for r in rows)
    untimed = sum(r["steps"] != "" and r["s_per_chunk"] == "" for r in rows)
    lines.append(f"{left / 3600:.1f} h of wall time left in the started cells at their recent chunk times"
                 + (f" ({untimed} started without a timed chunk, not counted)" if untimed else "")
                 + f"; {waiting} cell(s) known but not started")
    return "\n".join(lines)
