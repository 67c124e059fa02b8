"""The PPO comparison's numbers: the Brax PPO seeds against the nm-period actor-critic at the same
sample budgets, as ``results/baseline_ppo/summary.json`` and its markdown table hold them.

Read from run directories (``metrics.jsonl`` rows): PPO's deterministic evaluation at the iteration
boundary nearest each budget (10^6, 10^7, 2.5*10^7 control steps; a seed short of 98% of a budget
has not reached it), the actor-critic's deterministic evaluations at the same budgets
(``ac_milestones.json``, scripts/lab/ac_milestones.py), each as mean +/- the 95% t-interval over seeds
(:func:`nmrl.analysis.stats.mean_ci95`). scripts/publish/publish_baseline_ppo.py writes and draws them.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from nmrl.analysis import stats
from nmrl.runs import store

#: the budgets compared, in control steps over all environments
BUDGETS = {"1e6": 1e6, "1e7": 1e7, "2.5e7": 2.5e7}
#: the actor-critic's period lengths compared with PPO
AC_LS = (1, 10)
#: a seed has reached a budget when its last iteration is at least this share of it
REACHED = 0.98


def ppo_runs(src: pathlib.Path) -> dict[int, list[dict]]:
    """Every PPO seed's metrics rows under ``src/ppo_s{seed}`` (seeds without rows left out)."""
    runs = {}
    for d in sorted(src.glob("ppo_s*")):
        rows = store.read_metrics(d)
        if rows:
            runs[int(d.name[len("ppo_s"):])] = rows
    return runs


def ac_curves(points: pathlib.Path) -> dict[int, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """The actor-critic's learning curves of l in AC_LS: ``{l: {seed: (control steps over all
    environments, average reward per step)}}`` from a sweep's ``points/l{l}_s{seed}`` directories."""
    out: dict = {}
    for l in AC_LS:
        for d in sorted(points.glob(f"l{l}_s*")):
            cfg = json.loads((d / store.CONFIG_FILE).read_text())
            rows = store.read_metrics(d)
            x = np.array([r["step"] * cfg["num_envs"] for r in rows], float)
            y = np.array([r["avg_reward"] for r in rows], float)
            out.setdefault(l, {})[int(d.name.rsplit("_s", 1)[1])] = (x, y)
    return out


def nearest_row(rows: list[dict], budget: float) -> dict | None:
    """The row (an iteration with ``step`` > 0) nearest ``budget``; None while the seed's last row
    is short of REACHED x budget."""
    rows = [r for r in rows if r["step"] > 0]
    if not rows or rows[-1]["step"] < REACHED * budget:
        return None  # not reached yet
    return min(rows, key=lambda r: abs(r["step"] - budget))


def seed_entry(by_seed: dict[int, tuple[int, float, float]]) -> dict:
    """``{seed: (control steps, reward per step, speed)}`` as summary.json holds it: mean +/- 95%
    t-interval of the reward and the speed over the seeds, each seed's reward and steps."""
    steps, rew, spd = (np.array([v[i] for v in by_seed.values()], float) for i in range(3))
    m, h = stats.mean_ci95(rew)
    ms, hs = stats.mean_ci95(spd)
    return {"seeds": sorted(by_seed), "control_steps": [int(s) for s in steps], "avg_reward": m, "avg_reward_ci95": h,
            "per_seed": [float(x) for x in rew], "forward_speed": ms, "forward_speed_ci95": hs}


def summary(ppo: dict[int, list[dict]], ac: dict) -> dict:
    """Per method (``ppo``, ``ac_l1``, ``ac_l10``) and budget, the deterministic policies' entry
    (:func:`seed_entry`); a budget no seed of a method has reached is absent."""
    out: dict = {"ppo": {}, **{f"ac_l{l}": {} for l in AC_LS}}
    for name, budget in BUDGETS.items():
        got = {s: nearest_row(rows, budget) for s, rows in ppo.items()}
        got = {s: r for s, r in got.items() if r is not None}
        if got:
            out["ppo"][name] = seed_entry({s: (r["step"], r["eval_avg_reward"], r["eval_forward_speed"])
                                           for s, r in got.items()})
        for l in AC_LS:
            rows = [r for r in ac.get(name, {}).get("rows", []) if r["l"] == l]
            if rows:
                out[f"ac_l{l}"][name] = seed_entry({r["seed"]: (r["control_steps"], r["avg_reward"], r["forward_speed"])
                                                    for r in rows})
    return out


def table(summ: dict) -> str:
    """The summary as a markdown table: mean +/- interval (speed) per method and budget; one seed:
    its value and "seed N only" (no interval from one seed); not reached: a dash."""
    lines = ["| method | " + " | ".join(f"{k} steps" for k in BUDGETS) + " |", "|---|" + "---|" * len(BUDGETS)]
    names = {"ppo": "Brax PPO", **{f"ac_l{l}": f"actor-critic, l = {l}" for l in AC_LS}}
    for k, label in names.items():
        cells = []
        for b in BUDGETS:
            e = summ[k].get(b)
            if e is None:
                cells.append("—")
            elif len(e["seeds"]) < 2:  # no interval from one seed
                cells.append(f"{e['avg_reward']:+.2f}, seed {e['seeds'][0]} only ({e['forward_speed']:.2f} m/s)")
            else:
                cells.append(f"{e['avg_reward']:+.2f} ± {e['avg_reward_ci95']:.2f} ({e['forward_speed']:.2f} m/s)")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
