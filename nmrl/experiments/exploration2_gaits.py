"""The gaits of the best and the worst arm at 2.5 ms (docs/exploration-study-2.md, "Published").

Once every arm's 2.5 ms grid cell is complete (:data:`GAIT_ARMS`: W, Ws, OU, CN, NMs, NMp), the arms
are ranked by their cell's mean deterministic reward per second (the primary endpoint). For the best
and the worst arm, the run whose endpoint is the cell's median (the lower one of the middle two at
an even count) is the arm's typical policy: its deterministic policy is rolled out for the full
10 s from the robot's start (nmrl/analysis/evaluate.py: ``eval.json`` with its reward terms, ground
shares and strides, the 3-s strobe, the real-time ``gait.gif`` and ``trajectory.npz``), and the
whole 10 s are drawn as one strobe, a figure every 0.25 s (``strobe_10s.png``). ``gaits.json``
names the two arms, their runs and the numbers the pictures show. Each folder is made once per
saved step of its run; the measurement waits while a cell it needs is unfinished.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from nmrl.experiments import kit
from nmrl.experiments.exploration2_cells import grid_name
from nmrl.experiments.exploration2_rules import complete_cells
from nmrl.paper.control_step import DELTA_0
from nmrl.runs import store

GAITS = "gaits"  #: the measurement's folder in the study's directory (published whole)
GAIT_DT = 0.0025
GAIT_ARMS = ("white", "ws", "ou", "colored", "nms", "nmp")
SECONDS = 10.0
STROBE_EVERY_S = 0.25
STROBE_10S = "strobe_10s.png"


def chosen(rows: list[dict]) -> list[dict] | None:
    """``[best, worst]``, each {rank, arm, cell, point, seed, det_reward_per_s, cell_mean}; None
    while any 2.5 ms grid cell of :data:`GAIT_ARMS` is incomplete."""
    cells = complete_cells(rows)
    names = {arm: grid_name(arm, GAIT_DT) for arm in GAIT_ARMS}
    if any(n not in cells for n in names.values()):
        return None
    means = {arm: float(np.mean(cells[n])) for arm, n in names.items()}
    order = sorted(GAIT_ARMS, key=lambda a: means[a])
    out = []
    for rank, arm in (("best", order[-1]), ("worst", order[0])):
        mine = sorted((r for r in rows if r["cell"] == names[arm]), key=lambda r: float(r["det_reward_per_s"]))
        r = mine[(len(mine) - 1) // 2]
        out.append({"rank": rank, "arm": arm, "cell": names[arm], "point": r["point"], "seed": int(r["seed"]),
                    "det_reward_per_s": float(r["det_reward_per_s"]), "cell_mean": means[arm]})
    return out


def gaits(out: pathlib.Path, rows: list[dict]) -> None:
    """The measurement of the module docstring: ``out/gaits/<rank>_<arm>/`` and ``out/gaits/gaits.json``."""
    from nmrl.analysis import evaluate
    from nmrl.analysis.gait_pictures import plot_strobe

    pick = chosen(rows)
    if pick is None:
        return
    summary = []
    for c in pick:
        run = out / c["cell"] / "points" / c["point"]
        d = out / GAITS / f"{c['rank']}_{c['arm']}"
        ev = json.loads((d / evaluate.EVAL_JSON).read_text()) if (d / evaluate.EVAL_JSON).exists() else None
        step = json.loads((run / kit.ENDPOINT).read_text())["step"]
        if ev is None or ev.get("step") != step:
            ev = evaluate.evaluate(run, step, seconds=SECONDS, seed=0, out_dir=d, render=True)
            with np.load(d / evaluate.TRAJECTORY) as t:
                plot_strobe(t["pos"], float(t["control_dt"]), d / STROBE_10S, every_s=STROBE_EVERY_S,
                            span_s=SECONDS, title=f"{c['arm']} at 2.5 ms (the {c['rank']} arm), seed {c['seed']}, "
                                                  f"deterministic policy")
        det = ev["deterministic"]
        summary.append({**c, "step": step, "reward_per_s_from_start": det["avg_reward"] / DELTA_0,
                        "forward_speed": det["forward_speed"], "distance_m": det["distance"], "gait": det["gait"],
                        "ground_share": det["ground_share"]})
    store.atomic_write_json(out / GAITS / "gaits.json", summary)
