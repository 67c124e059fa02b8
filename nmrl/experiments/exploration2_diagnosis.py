"""Why study 2's period-wise nm-period arm (NMp) did not learn: its trust region and clipping against
white's, per iteration, from the grid runs' own logs, and the diagnosis runs' endpoints.

PPO logs per iteration the share of clipped ratios (``clip_frac``) and the k3 estimate of
KL(old || new) per ratio (``approx_kl``): per control step for white, per period for NMp (one ratio
per period, eq. (7)). A KL per ratio divided by the seconds a ratio covers (delta; NMp: its period)
is the KL per second of behaviour, the trust region in physical units (the KL of a product of
independent factors is their sum). :func:`trust_region` gives, per cell and iteration, the median
over seeds of both; :func:`figure` draws them (``trust_region.png``).

    python -m nmrl.experiments.exploration2_diagnosis results/exploration2/runs   # writes the table and figure there
"""

from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

from nmrl.runs import store

#: the cells compared (study 2's grid): white and NMp at 20 and 2.5 ms
CELLS = ("grid/dt0.02/white", "grid/dt0.02/nmp", "grid/dt0.0025/white", "grid/dt0.0025/nmp")
TABLE, FIGURE = "trust_region.csv", "trust_region.png"
COLUMNS = ("cell", "iteration", "seeds", "seconds_per_ratio", "clip_frac", "kl_per_ratio", "kl_per_s")


def seconds_per_ratio(config: dict) -> float:
    """The behaviour one PPO ratio covers [s]: the period when period-wise, else the control step."""
    return float(config["period_s"]) if config.get("period_wise") else float(config["control_dt"])


def trust_region(record: pathlib.Path, cells: tuple[str, ...] = CELLS) -> list[dict]:
    """Per cell (default :data:`CELLS`) and iteration: the median over seeds of the clipped share and
    of the KL per ratio and per second of behaviour."""
    out = []
    for cell in cells:
        points = sorted((record / cell / "points").glob("*/metrics.jsonl"))
        if not points:
            continue
        per = seconds_per_ratio(json.loads((points[0].parent / "config.json").read_text()))
        logs = [[json.loads(x) for x in p.read_text().splitlines() if x.strip()] for p in points]
        for it in range(min(len(m) for m in logs)):
            clip = np.median([m[it]["clip_frac"] for m in logs])
            kl = np.median([m[it]["approx_kl"] for m in logs])
            out.append({"cell": cell, "iteration": it + 1, "seeds": len(logs), "seconds_per_ratio": per,
                        "clip_frac": float(clip), "kl_per_ratio": float(kl), "kl_per_s": float(kl / per)})
    return out


def figure(rows: list[dict], path: pathlib.Path) -> pathlib.Path:
    """Two panels against the iteration: the clipped share of ratios, and the KL per second of
    behaviour (log scale), a line per cell."""
    from nmrl.analysis import plots

    plt = plots.plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8), layout="constrained")
    for i, cell in enumerate(dict.fromkeys(r["cell"] for r in rows)):
        rs = [r for r in rows if r["cell"] == cell]
        it = [r["iteration"] for r in rs]
        label = cell.removeprefix("grid/").replace("dt", "").replace("/", " s, ")
        style = "-" if cell.endswith("white") else "--"
        a.plot(it, [r["clip_frac"] for r in rs], style, marker="o", ms=3, color=f"C{i}", label=label)
        b.plot(it, [r["kl_per_s"] for r in rs], style, marker="o", ms=3, color=f"C{i}", label=label)
    a.set_ylabel("share of ratios clipped (median over seeds)")
    b.set_ylabel("approx. KL per second of behaviour (median)")
    b.set_yscale("log")
    for ax in (a, b):
        ax.set_xlabel("PPO iteration")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("study 2: white (per control step) against NMp (per period), the grid's logs")
    plots.save(fig, path, dpi=110, bbox_inches="tight")
    return path


def summary(rows: list[dict], first: int = 2) -> dict[str, dict]:
    """Per cell: the median over iterations ``first``.. of the (per-iteration median) clipped share
    and KL per second, leaving out the first iteration's jump of the observation statistics."""
    out = {}
    for cell in dict.fromkeys(r["cell"] for r in rows):
        rs = [r for r in rows if r["cell"] == cell and r["iteration"] >= first]
        if rs:
            out[cell] = {"clip_frac": float(np.median([r["clip_frac"] for r in rs])),
                         "kl_per_s": float(np.median([r["kl_per_s"] for r in rs])), "iterations": len(rs)}
    return out


def main(argv: list[str] | None = None) -> int:
    record = pathlib.Path((argv if argv is not None else sys.argv[1:])[0])
    rows = trust_region(record)
    store.write_csv(record / TABLE, COLUMNS, rows)
    figure(rows, record / FIGURE)
    return 0


if __name__ == "__main__":
    sys.exit(main())
