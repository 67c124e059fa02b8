"""Each grid policy with its own exploration noise scaled by k (docs/exploration-study-2.md, "Results").

A check that decides nothing, added after grid cells showed deterministic policies that stand while
the same policies with their noise walk: is the walking carried by the noise? For every ended run of
a complete grid cell, the policy the endpoint scored (its last saved step; a diverged run's last good
one) is rolled out as the endpoint rolls it (the study's :data:`ENDPOINT`: 8 rollouts of 10 s from
the same perturbed starts, trials never stopping) with ``k xi_t``, xi_t the run's own exploration
process, for every k in :data:`NOISE_SCALES` (nmrl/analysis/endpoint.py, ``noisy_endpoint``: the
same noise draws at every k, so that k alone differs). k = 0 is the deterministic endpoint, k = 1
the exploring policy as trained, here without the training's trial stops.

``noise_scales.csv``: one row per run and k (its step, reward per second, forward speed); rows of
a run already there at its endpoint's step are kept (read from ``endpoint.json``, so a call that
adds nothing restores no policy: the measurement runs after every cell). :func:`figure`
draws ``noise_scales.png`` from it: reward per second and forward speed against k, one column per
control step, each arm's mean over its runs with its 95% t band.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from nmrl.experiments.exploration2_cells import ARM_COLORS, ARM_ORDER, ENDPOINT, arm_and_dt
from nmrl.experiments.exploration2_rules import complete_cells, ended
from nmrl.experiments.kit import ENDPOINT as ENDPOINT_FILE
from nmrl.runs import store

NOISE_CSV = "noise_scales.csv"
NOISE_FIGURE = "noise_scales.png"
NOISE_SCALES = (0.0, 0.25, 0.5, 1.0)
COLUMNS = ("cell", "point", "seed", "step", "noise_scale", "reward_per_s", "forward_speed")


def noise_scales(out: pathlib.Path, rows: list[dict]) -> None:
    """The measurement of the module docstring into ``out/noise_scales.csv`` (written after every run)."""
    from nmrl.analysis import endpoint
    from nmrl.runs import checkpoint

    path = out / NOISE_CSV
    done = store.read_csv(path) if path.is_file() else []
    have = {(r["cell"], r["point"], int(r["step"])) for r in done}
    cells = {c for c in complete_cells(rows) if c.startswith("grid/")}
    for r in rows:
        if r["cell"] not in cells or not ended(r):
            continue
        point = out / r["cell"] / "points" / r["point"]
        step = int(json.loads((point / ENDPOINT_FILE).read_text())["step"])  # the policy the endpoint scored
        if (r["cell"], r["point"], step) in have:
            continue
        _, config, params = checkpoint.restore_params(point, step)
        done = [d for d in done if (d["cell"], d["point"]) != (r["cell"], r["point"])]
        for k in NOISE_SCALES:
            e = endpoint.noisy_endpoint(config, params, k, seconds=ENDPOINT.seconds, rollouts=ENDPOINT.rollouts,
                                        start_noise=ENDPOINT.start_noise, seed=ENDPOINT.seed)
            done.append({"cell": r["cell"], "point": r["point"], "seed": int(r["seed"]), "step": step,
                         "noise_scale": k, "reward_per_s": e["reward_per_s"],
                         "forward_speed": float(np.mean(e["forward_speed"]))})
        store.write_csv(path, COLUMNS, done)


def figure(dest: pathlib.Path) -> None:
    """``noise_scales.png`` from ``dest/noise_scales.csv`` (see the module docstring)."""
    from nmrl.analysis import plots
    from nmrl.analysis.cell_curves import draw

    got = store.read_csv(dest / NOISE_CSV)
    runs: dict[float, dict[str, dict[str, list[tuple[float, float, float]]]]] = {}
    for r in got:
        arm, dt = arm_and_dt(r["cell"])
        runs.setdefault(dt, {}).setdefault(arm, {}).setdefault(r["point"], []).append(
            (float(r["noise_scale"]), float(r["reward_per_s"]), float(r["forward_speed"])))
    dts = sorted(runs, reverse=True)
    fig, axes = plots.plt.subplots(2, len(dts), figsize=(4.6 * len(dts), 7.0), sharey="row", squeeze=False,
                                   layout="constrained")
    for j, dt in enumerate(dts):
        arms = sorted(runs[dt], key=ARM_ORDER.index)
        for i, col in enumerate((1, 2)):
            cells = {arm: [(np.array([x[0] for x in sorted(p)]), np.array([x[col] for x in sorted(p)]))
                           for p in runs[dt][arm].values()] for arm in arms}
            draw(axes[i][j], cells, ARM_COLORS)
            axes[i][j].set_title(f"control step {dt * 1000:g} ms")
            axes[i][j].set_xlabel("noise scale k (x the exploration noise it was trained with)")
    axes[0][0].set_ylabel("reward per second")
    axes[1][0].set_ylabel("forward speed [m/s]")
    fig.suptitle("every ended grid policy with its own noise times k, 8 rollouts of 10 s from perturbed starts")
    plots.save(fig, dest / NOISE_FIGURE, dpi=110, bbox_inches="tight")
