"""PPO on Gymnasium's HalfCheetah-v5: nmrl's PPO against Brax's PPO at the same settings, as returns per episode.

Both learners report, per PPO iteration, the average reward per control step of the exploring
policy over every step of the iteration's rollouts (native: a sweep point's ``avg_reward``, one chunk
per iteration; Brax: ``train_reward_per_step``, nmrl/adapters/brax_env.py's tally), against control
steps summed over the environments. HalfCheetah's episodes all last its time limit, 1,000 control
steps (it has no termination), so the return of an episode is 1,000 times its average reward per
step; the learning curves are that return, ``EPISODE_STEPS x`` the iteration's average reward per
step (a mean over the iteration's steps, which belong to partial episodes as well as whole ones).

The deterministic policies (Brax's mode, the native ``xi = 0``) are scored by the mean return of 10
episodes from the same reset states (nmrl.analysis.task_eval: ``nmrl eval`` for the native points,
``eval_return`` in the Brax rows), compared at a control step both reached, with the Welch 95%
interval of the difference (:func:`nmrl.analysis.stats.diff_ci95`). The seed band of a learner at an
iteration is [min, max] over its seeds (nmrl.analysis.ppo_validation.band).
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from nmrl.analysis import ppo_validation as pv, stats
from nmrl.runs import store

#: HalfCheetah-v5's episode length (its time limit, no termination)
EPISODE_STEPS = 1000

Curves = dict[int, tuple[np.ndarray, np.ndarray]]


def native_returns(points: pathlib.Path) -> Curves:
    """``{seed: (control steps, return per episode)}`` of a native sweep's ``points/s{seed}``."""
    return {s: (x, EPISODE_STEPS * y) for s, (x, y) in pv.native_curves(points).items()}


def brax_runs(root: pathlib.Path) -> dict[int, list[dict]]:
    """``{seed: metrics rows}`` of the Brax runs ``root/ppo_s{seed}``."""
    out = {}
    for d in sorted(root.glob("ppo_s*")):
        rows = store.read_metrics(d) if (d / store.METRICS_FILE).is_file() else []
        if rows:
            out[int(d.name[len("ppo_s"):])] = rows
    return out


def brax_returns(runs: dict[int, list[dict]]) -> Curves:
    """``{seed: (control steps, return per episode)}`` of the Brax seeds' rows."""
    return {s: (x, EPISODE_STEPS * y) for s, (x, y) in pv.peer_curves(runs).items()}


def curve_rows(native: Curves, brax: Curves) -> list[dict]:
    """One row per learner, seed and iteration: the learning curves as a table."""
    rows = []
    for name, curves in (("native", native), ("brax", brax)):
        for s, (x, y) in sorted(curves.items()):
            rows += [{"learner": name, "seed": s, "control_steps": int(a), "return_per_episode": float(b)}
                     for a, b in zip(x, y)]
    return rows


def common_step(native_evals: dict[int, dict], runs: dict[int, list[dict]], num_envs: int) -> int | None:
    """The control step (all environments) of the native evaluations when every native seed was
    evaluated at the same one and every Brax seed has a row evaluated there; else None."""
    steps = {int(e["step"]) * num_envs for e in native_evals.values()}
    if len(steps) != 1:
        return None
    step = steps.pop()
    have = all(any(r["step"] == step and r.get("eval_return") is not None for r in rows) for rows in runs.values())
    return step if have and runs else None


def deterministic(native_evals: dict[int, dict], runs: dict[int, list[dict]], step: int) -> dict:
    """Both learners' deterministic returns at ``step``: per seed, mean +/- 95% t interval, and
    native - Brax with its Welch 95% interval."""
    nat = {s: float(e["deterministic"]["return"]["mean"]) for s, e in sorted(native_evals.items())}
    brx = {s: float(next(r["eval_return"] for r in rows if r["step"] == step)) for s, rows in sorted(runs.items())}
    out = {"control_steps": int(step)}
    for name, per in (("native", nat), ("brax", brx)):
        m, h = stats.mean_ci95(np.array(list(per.values()), float))
        out[name] = {"mean": m, "ci95": h, "per_seed": {str(s): v for s, v in per.items()}}
    d, h = stats.diff_ci95(np.array(list(brx.values())), np.array(list(nat.values())))
    out["native_minus_brax"] = {"diff": d, "ci95_welch": h}
    return out


def summary(native: Curves, brax: Curves, native_evals: dict[int, dict], runs: dict[int, list[dict]],
            num_envs: int) -> dict:
    """The band check per iteration both reached (native mean within the Brax seeds' min..max), the
    steps each seed reached, and, where a common evaluated step exists, :func:`deterministic`."""
    rows = pv.band_check(native, pv.band(brax)) if native and brax else []
    step = common_step(native_evals, runs, num_envs) if native_evals else None
    return {"iterations": rows, "within_band": sum(r["within"] for r in rows), "of": len(rows),
            "native_last_steps": {str(s): int(x.max()) for s, (x, _) in sorted(native.items())},
            "brax_last_steps": {str(s): int(x.max()) for s, (x, _) in sorted(brax.items())},
            "deterministic": deterministic(native_evals, runs, step) if step is not None else None}


def read_evals(points: pathlib.Path) -> dict[int, dict]:
    """``{seed: eval.json}`` of a published sweep's points (``points/s{seed}/eval.json``)."""
    return {int(p.name[1:]): json.loads((p / "eval.json").read_text())
            for p in sorted(points.glob("s*")) if (p / "eval.json").is_file()}
