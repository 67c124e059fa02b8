"""Publish the native PPO's validation against the Brax PPO peer under results/ppo/.

    .venv/bin/python scripts/publish/publish_ppo_validation.py [--src runs/ppo_validation] [--dest results/ppo]

Reads the sweep SRC (scripts/run/ppo_validation.sh: nmrl's PPO, white noise, the Brax settings, 3
seeds) and the Brax seeds' metrics (results/baseline_ppo/ppo_s*/metrics.jsonl). Writes, atomically:

* ``validation/{sweep.json, points/s{seed}/{config.json, metrics.jsonl, compact.npz}}``: what a
  fresh clone needs to continue the sweep (scripts/run/ppo_validation.sh seeds runs/ from it);
* ``learning_curves.png``: average reward per control step during learning against control steps,
  each native seed and their mean over the band (min..max) of the Brax seeds;
* ``summary.json``: per iteration both seed sets reached, the native mean, the Brax band and whether
  the mean lies within it; the Brax deterministic policies at the native run's last step and, where
  every native point has been evaluated (``nmrl eval SRC/points/s{seed} --seconds 10``: the same 10 s
  rollout from seed 0 as the Brax evaluations), the native ones and the difference (Welch interval).

With ``--against-native POINTS`` the peer is another native sweep instead of Brax: its points'
metrics give the band and their ``eval.json`` the deterministic policies (the C physics' learning
check: ``--src runs/ppo_validation_c --dest results/physics_c/ppo
--against-native results/ppo/validation/points``, the MJX runs as the band).

The numbers are nmrl/analysis/ppo_validation.py's; this script copies, draws and writes.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from nmrl.analysis import ppo_validation as pv, stats
from nmrl.analysis.publish_ppo import ppo_runs
from nmrl.runs import store

ROOT = pathlib.Path(__file__).resolve().parents[2]


def draw(native: dict, peer: dict, path: pathlib.Path, names: tuple[str, str] = ("native PPO", "Brax PPO"),
         title: str = "Native PPO (white noise) vs Brax PPO, the same robot and settings") -> None:
    from nmrl.analysis.plots import plt, save

    fig, ax = plt.subplots(figsize=(8, 4.8), dpi=110)
    steps, lo, hi = pv.band(peer)
    ax.fill_between(steps, lo, hi, color="C3", alpha=0.25, label=f"{names[1]}, {len(peer)} seeds (min..max)")
    for i, (s, (x, y)) in enumerate(sorted(native.items())):
        ax.plot(x, y, color="C0", lw=0.8, alpha=0.5, label=f"{names[0]}, each seed" if i == 0 else None)
    if native:
        common = sorted(set.intersection(*(set(x.tolist()) for x, _ in native.values())))
        mean = [np.mean([y[list(x).index(c)] for x, y in native.values()]) for c in common]
        ax.plot(common, mean, color="C0", lw=2, label=f"{names[0]}, mean of {len(native)} seeds")
    xmax = max([x.max() for x, _ in native.values()], default=steps.max())
    ax.set_xlim(0, max(xmax * 1.05, 1))
    ax.set_xlabel("control steps (all environments)")
    ax.set_ylabel("average reward per control step during learning")
    ax.set_title(title)
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    save(fig, path)


def _evals(points: pathlib.Path) -> dict[int, dict]:
    """``{seed: eval.json}`` of a published sweep's points (each ``points/s{seed}/eval.json``)."""
    return {int(p.name[1:]): json.loads((p / "eval.json").read_text())
            for p in sorted(points.glob("s*")) if (p / "eval.json").is_file()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", default="runs/ppo_validation")
    ap.add_argument("--dest", default="results/ppo")
    ap.add_argument("--peer", default="results/baseline_ppo")
    ap.add_argument("--against-native", default=None, metavar="POINTS",
                    help="a published native sweep's points/ as the peer (instead of Brax)")
    a = ap.parse_args()
    src, dest, peer_dir = (ROOT / p for p in (a.src, a.dest, a.peer))
    if (src / "sweep.json").is_file():
        store.atomic_copy(src / "sweep.json", dest / "validation" / "sweep.json")
        for p in sorted((src / "points").glob("s*")):
            for name in ("config.json", "metrics.jsonl", "compact.npz"):
                if (p / name).is_file():
                    store.atomic_copy(p / name, dest / "validation" / "points" / p.name / name)
            if (p / "eval" / "eval.json").is_file():
                store.atomic_copy(p / "eval" / "eval.json", dest / "validation" / "points" / p.name / "eval.json")
    native = pv.native_curves(dest / "validation" / "points")
    evals = _evals(dest / "validation" / "points")
    last = min((x.max() for x, _ in native.values()), default=0.0)
    if a.against_native:
        peer_points = ROOT / a.against_native
        peer = pv.native_curves(peer_points)
        peer_evals = _evals(peer_points)
        on = lambda ev: "/".join(sorted({e.get("physics", "mjx") for e in ev.values()})) or "?"  # noqa: E731
        draw(native, peer, dest / "learning_curves.png",
             names=(f"native PPO on {on(evals)}", f"native PPO on {on(peer_evals)}"),
             title="Native PPO (white noise), the same settings on two physics")
        peer_det = pv.native_deterministic(peer_evals) if sorted(peer_evals) == sorted(peer) else None
        peer_name = "peer"
    else:
        runs = ppo_runs(peer_dir)
        peer = pv.peer_curves(runs)
        draw(native, peer, dest / "learning_curves.png")
        peer_det = pv.deterministic_at(runs, last) if last else None
        peer_name = "brax"
    rows = pv.band_check(native, pv.band(peer))
    out = {"iterations": rows, "within_band": sum(r["within"] for r in rows), "of": len(rows),
           "native_seeds": sorted(native), "native_last_steps": {str(s): int(x.max()) for s, (x, _) in native.items()},
           "peer": a.against_native or a.peer,
           f"{peer_name}_deterministic_at_native_last": peer_det}
    if native and sorted(evals) == sorted(native):
        out["native_deterministic"] = pv.native_deterministic(evals)
        out["native_physics"] = sorted({e.get("physics", "mjx") for e in evals.values()})
        if peer_det:
            d, h = stats.diff_ci95(np.array(list(peer_det["per_seed"].values())),
                                   np.array(list(out["native_deterministic"]["per_seed"].values())))
            out[f"native_minus_{peer_name}_deterministic"] = {"diff": d, "ci95": h}
    store.atomic_write_json(dest / "summary.json", out)
    print(json.dumps({k: out[k] for k in ("within_band", "of", "native_last_steps")}))
    for r in rows:
        print(f"{r['control_steps']:>9d}  native {r['native_mean']:+.3f}  {peer_name} [{r['peer_lo']:+.3f}, {r['peer_hi']:+.3f}]"
              f"  {'within' if r['within'] else 'OUTSIDE'}")


if __name__ == "__main__":
    main()
