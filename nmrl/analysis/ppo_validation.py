"""The native PPO against the Brax PPO peer on the same robot: learning curves and the band test.

Both learners report, per PPO iteration, the average reward per control step of the exploring
policy over every step of the iteration's rollouts (native: the chunk's ``avg_reward``, one chunk per
iteration; Brax: ``train_reward_per_step``, nmrl/adapters/brax_env.py's tally), against control
steps summed over the environments (native: ``step`` x ``num_envs``; Brax: ``step``). At equal
settings both take the same 327,680 control steps per iteration, so the curves share their x values.

The band of the peer at an iteration is [min, max] over its seeds; the native curve lies within it
at an iteration when the mean over the native seeds does. The deterministic policies are compared by
their mean +/- 95% t-interval over seeds (:func:`nmrl.analysis.stats.mean_ci95`).
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from nmrl.analysis import stats
from nmrl.runs import store


def native_curves(points: pathlib.Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{seed: (control steps over all environments, avg_reward)}`` of a sweep's ``points/s{seed}``."""
    out = {}
    for d in sorted(points.glob("s*")):
        if not (d / store.CONFIG_FILE).is_file():
            continue
        cfg = json.loads((d / store.CONFIG_FILE).read_text())
        rows = store.read_metrics(d)
        if rows:
            out[int(d.name[1:])] = (np.array([r["step"] * cfg["num_envs"] for r in rows], float),
                                    np.array([r["avg_reward"] for r in rows], float))
    return out


def peer_curves(runs: dict[int, list[dict]]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{seed: (control steps, train_reward_per_step)}`` of the Brax seeds' metrics rows."""
    out = {}
    for s, rows in runs.items():
        r = [x for x in rows if x.get("train_reward_per_step") is not None]
        out[s] = (np.array([x["step"] for x in r], float), np.array([x["train_reward_per_step"] for x in r], float))
    return out


def band(curves: dict[int, tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(steps, lo, hi)``: the control steps every seed reached, and min / max over the seeds there."""
    common = sorted(set.intersection(*(set(x.tolist()) for x, _ in curves.values())))
    ys = np.array([[y[list(x).index(s)] for s in common] for x, y in curves.values()])
    return np.array(common, float), ys.min(axis=0), ys.max(axis=0)


def band_check(native: dict[int, tuple[np.ndarray, np.ndarray]], peer_band) -> list[dict]:
    """One row per control-step count that every native seed and the peer's band have: the native
    mean over seeds, the band, and whether the mean lies within it."""
    steps, lo, hi = peer_band
    have = set.intersection(*(set(x.tolist()) for x, _ in native.values())) if native else set()
    rows = []
    for i, s in enumerate(steps):
        if s not in have:
            continue
        vals = np.array([y[list(x).index(s)] for x, y in native.values()])
        m = float(vals.mean())
        rows.append({"control_steps": int(s), "native_mean": m, "native_seeds": [float(v) for v in vals],
                     "peer_lo": float(lo[i]), "peer_hi": float(hi[i]), "within": bool(lo[i] <= m <= hi[i])})
    return rows


def deterministic_at(runs: dict[int, list[dict]], steps: float, key: str = "eval_avg_reward") -> dict | None:
    """The peer's deterministic evaluations at the iteration nearest ``steps`` (every seed that has
    one within 2% of it): mean +/- 95% interval, each seed's value and step; None if no seed has."""
    got = {}
    for s, rows in runs.items():
        r = [x for x in rows if x.get(key) is not None and x["step"] > 0]
        if r:
            best = min(r, key=lambda x: abs(x["step"] - steps))
            if abs(best["step"] - steps) <= 0.02 * steps + 327_680:
                got[s] = (best["step"], best[key])
    if not got:
        return None
    vals = np.array([v for _, v in got.values()], float)
    m, h = stats.mean_ci95(vals)
    return {"mean": m, "ci95": h, "per_seed": {str(s): v for s, (_, v) in got.items()},
            "steps": {str(s): int(st) for s, (st, _) in got.items()}}


def native_deterministic(evals: dict[int, dict]) -> dict:
    """The native points' deterministic evaluations (``nmrl eval``'s ``eval.json`` per seed, whose
    ``deterministic`` part holds the policy's mode): mean +/- 95% interval of ``avg_reward``, each
    seed's value and the step it was taken at."""
    per = {s: float(e["deterministic"]["avg_reward"]) for s, e in evals.items()}
    m, h = stats.mean_ci95(np.array(list(per.values()), float))
    return {"mean": m, "ci95": h, "per_seed": {str(s): v for s, v in per.items()},
            "steps": {str(s): e.get("step") for s, e in evals.items()}}
