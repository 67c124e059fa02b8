"""The gait of a study's chosen runs, drawn from their deterministic policies.

A study that shows its arms' gaits picks a run per arm, usually the run whose endpoint is its
cell's median (:func:`median_run`: the lower of the middle two at an even count, so that the run
shown is one that happened, not an average of two), and :func:`draw` rolls each picked run's
deterministic policy out for ``seconds`` from the robot's start (nmrl/analysis/evaluate.py:
``eval.json`` with its reward terms, ground shares and strides, the 3-s strobe, the real-time
``gait.gif`` and ``trajectory.npz``) and draws the whole rollout as one strobe, a figure every
``every_s`` (``strobe_10s.png``). ``gaits.json`` names the picked runs and the numbers the pictures
show. A folder is made once per saved step of its run: a later call with the same step reads it.
"""

from __future__ import annotations

import json
import pathlib
from typing import Callable, Iterable

import numpy as np

from nmrl.experiments.kit import ENDPOINT
from nmrl.paper.control_step import DELTA_0
from nmrl.runs import store

GAITS = "gaits"  #: the measurement's folder in the study's directory (published whole)
SECONDS = 10.0
STROBE_EVERY_S = 0.25
STROBE_10S = "strobe_10s.png"
SUMMARY = "gaits.json"


def median_run(rows: Iterable[dict]) -> dict:
    """The row whose ``det_reward_per_s`` is the lower median of ``rows``."""
    mine = sorted(rows, key=lambda r: float(r["det_reward_per_s"]))
    if not mine:
        raise ValueError("no rows to take a median run of")
    return mine[(len(mine) - 1) // 2]


def pick(rows: Iterable[dict], **label) -> dict:
    """The median run of ``rows`` (:func:`median_run`) as a gait's pick: ``label`` (its name, arm,
    cell, its cell's mean...) with the run's ``point``, ``seed`` and ``det_reward_per_s``."""
    r = median_run(rows)
    return {**label, "point": r["point"], "seed": int(r["seed"]), "det_reward_per_s": float(r["det_reward_per_s"])}


def draw(out: pathlib.Path, picks: list[dict], title: Callable[[dict], str]) -> None:
    """Each pick (a dict with at least ``name``, the folder under ``out/gaits``, and the run's ``cell``
    and ``point``) rolled out and drawn (module docstring), titled ``title(pick)``; ``gaits.json`` lists
    the picks (without ``name``) with the rollout's numbers."""
    from nmrl.analysis import evaluate
    from nmrl.analysis.gait_pictures import plot_strobe

    summary = []
    for c in picks:
        run = out / c["cell"] / "points" / c["point"]
        d = out / GAITS / c["name"]
        ev = json.loads((d / evaluate.EVAL_JSON).read_text()) if (d / evaluate.EVAL_JSON).exists() else None
        step = json.loads((run / ENDPOINT).read_text())["step"]
        if ev is None or ev.get("step") != step:
            ev = evaluate.evaluate(run, step, seconds=SECONDS, seed=0, out_dir=d, render=True)
            with np.load(d / evaluate.TRAJECTORY) as t:
                plot_strobe(t["pos"], float(t["control_dt"]), d / STROBE_10S, every_s=STROBE_EVERY_S,
                            span_s=SECONDS, title=title(c))
        det = ev["deterministic"]
        summary.append({**{k: v for k, v in c.items() if k != "name"}, "step": step,
                        "reward_per_s_from_start": det["avg_reward"] / DELTA_0,
                        "forward_speed": det["forward_speed"], "distance_m": det["distance"], "gait": det["gait"],
                        "ground_share": det["ground_share"]})
    store.atomic_write_json(out / GAITS / SUMMARY, summary)
