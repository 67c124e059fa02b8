"""When does PPO's deterministic policy start to walk, against its exploring one? Study 2's W(20)
and NMp(20) cells (nmrl/experiments/exploration2_cells.py: 64 environments, C physics at a 2.5 ms
timestep, trials of 5 s) for seeds 0-1, brought to their budget in stages (each stage a resume of
the same sweep with a larger ``--steps``, so the stages are one run), the policy at every stage's end
rolled out without noise (the study's deterministic endpoint: 8 rollouts of 10 s from perturbed
starts) and with its own noise (k = 1, study 2's noise-scale check).

At study 2's budget (16 iterations) W(20)'s deterministic policy walks and NMp(20)'s stands while its
exploring policy moves. This separates two explanations: period-wise PPO learns a gait that lives in
the noise and never in the mean, or it learns the same way as white PPO, slower, and the mean's gait
comes after the exploring policy's in both. NMp runs on to twice study 2's budget.

    python scripts/lab/gait_stages.py --out runs/gait_stages --arm white    # resumable; one arm per process
    python scripts/lab/gait_stages.py --out runs/gait_stages --arm nmp
    python scripts/lab/gait_stages.py --out runs/gait_stages --publish results/exploration2/diagnosis/stages

``stages.csv`` holds one row per arm, seed and stage: the iteration, the exploring policy's training
speed in that iteration, and both rollouts' reward per second and forward speed; ``stages.png``
draws the three speeds by iteration, a panel per arm.
"""

from __future__ import annotations

import argparse
import json
import pathlib

from nmrl.experiments import kit
from nmrl.experiments.exploration2_cells import ARMS, ENDPOINT, ITERATION_S
from nmrl.experiments.exploration2_cells import cell as e2cell

SEEDS = 2
CONTROL_DT = 0.02
#: the iterations at which each arm's policies are rolled out (study 2's budget is 16)
STAGES = {"white": (4, 6, 8, 10, 12, 14, 16), "nmp": (4, 8, 12, 16, 20, 24, 28, 32)}
COLUMNS = ("arm", "point", "seed", "iteration", "step", "train_forward_speed", "det_reward_per_s",
           "det_forward_speed", "noisy_reward_per_s", "noisy_forward_speed")
CSV = "stages.csv"


def cell(arm: str, iterations: int) -> kit.Cell:
    """``arm``'s cell at 20 ms with a budget of ``iterations`` PPO iterations (the same directory at every budget)."""
    return e2cell(f"dt{CONTROL_DT:g}/{arm}", CONTROL_DT, iterations, ARMS[arm], seeds=SEEDS, seed0=0,
                  run_options={"group": SEEDS})


def measure(arm: str, d: pathlib.Path, iteration: int) -> list[dict]:
    """Each point's policy at ``iteration`` rolled out without and with its noise (module docstring)."""
    import numpy as np

    from nmrl.analysis import endpoint
    from nmrl.runs import checkpoint

    step = round(iteration * ITERATION_S / CONTROL_DT)
    rows = []
    for p in kit.point_dirs(d):
        meta, config, params = checkpoint.restore_params(p, step)
        train = [json.loads(line) for line in (p / "metrics.jsonl").read_text().splitlines() if line.strip()]
        speed = next(float(m["forward_speed"]) for m in train if int(m["step"]) == step)
        e = dict(seconds=ENDPOINT.seconds, rollouts=ENDPOINT.rollouts, start_noise=ENDPOINT.start_noise,
                 seed=ENDPOINT.seed)
        det = endpoint.deterministic_endpoint(config, params, **e)
        noisy = endpoint.noisy_endpoint(config, params, 1.0, **e)
        rows.append({"arm": arm, "point": p.name, "seed": int(config.budget.seed), "iteration": iteration,
                     "step": int(meta["step"]), "train_forward_speed": speed,
                     "det_reward_per_s": det["reward_per_s"], "det_forward_speed": float(np.mean(det["forward_speed"])),
                     "noisy_reward_per_s": noisy["reward_per_s"],
                     "noisy_forward_speed": float(np.mean(noisy["forward_speed"]))})
    return rows


def run(out: pathlib.Path, arm: str) -> None:
    """Bring ``arm`` through its stages, measuring each once (a rerun continues where it stopped)."""
    from nmrl.runs import store

    study = kit.Study(name="gait_stages", cells=(), endpoint=None)
    f = out / arm / CSV
    rows = store.read_csv(f) if f.is_file() else []
    done = {int(r["iteration"]) for r in rows}
    for it in STAGES[arm]:
        c = cell(arm, it)
        kit.run_cell(study, c, out)
        if it in done:
            continue
        new = measure(arm, out / c.name, it)
        for r in new:
            print(f"{arm} {r['point']} iteration {it}: training {r['train_forward_speed']:.2f} m/s; deterministic "
                  f"{r['det_reward_per_s']:.1f} /s at {r['det_forward_speed']:.2f} m/s; noisy {r['noisy_reward_per_s']:.1f}"
                  f" /s at {r['noisy_forward_speed']:.2f} m/s", flush=True)
        rows += new
        f.parent.mkdir(parents=True, exist_ok=True)
        store.write_csv(f, COLUMNS, rows)


def publish(out: pathlib.Path, dest: pathlib.Path) -> None:
    """Every arm's stages into one ``stages.csv`` at ``dest``, and each cell's continuation files."""
    from nmrl.runs import store

    rows = []
    for arm in STAGES:
        if (out / arm / CSV).is_file():
            rows += store.read_csv(out / arm / CSV)
        d = out / cell(arm, STAGES[arm][0]).name
        if (d / "sweep.json").is_file():
            kit.copy_cell(d, dest / d.relative_to(out))
    dest.mkdir(parents=True, exist_ok=True)
    store.write_csv(dest / CSV, COLUMNS, rows)
    figure(rows, dest / FIGURE)


FIGURE = "stages.png"


def figure(rows: list[dict], path: pathlib.Path) -> None:
    """A panel per arm: each seed's forward speed in training, without noise and with it, by iteration."""
    from nmrl.analysis.plots import plt, save

    fig, axes = plt.subplots(1, len(STAGES), figsize=(10, 3.6), sharey=True)
    styles = {"train_forward_speed": ("training (exploring)", "C0"), "noisy_forward_speed": ("rollout with its noise", "C1"),
              "det_forward_speed": ("deterministic rollout", "C3")}
    for ax, arm in zip(axes, STAGES):
        for seed, ls in ((0, "-"), (1, "--")):
            rs = sorted((r for r in rows if r["arm"] == arm and int(r["seed"]) == seed), key=lambda r: int(r["iteration"]))
            its = [int(r["iteration"]) for r in rs]
            for key, (label, colour) in styles.items():
                ax.plot(its, [float(r[key]) for r in rs], ls, color=colour, marker="o", ms=3,
                        label=f"{label}" if seed == 0 else None)
        ax.axvline(16, color="0.6", lw=0.8)
        ax.set_title({"white": "W(20): white noise, per-step ratios", "nmp": "NMp(20): nm-periods learned on periods"}[arm],
                     fontsize=9)
        ax.set_xlabel("PPO iteration (the grid's budget: 16)")
    axes[0].set_ylabel("forward speed, m/s")
    fig.suptitle("seeds 0 (solid) and 1 (dashed); a policy rolled out at the end of each stage", fontsize=9)
    axes[0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    save(fig, path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--arm", choices=sorted(STAGES), help="run this arm's stages (one arm per process)")
    ap.add_argument("--publish", metavar="DEST", help="copy the stages and the cells' continuation files to DEST")
    a = ap.parse_args()
    out = pathlib.Path(a.out)
    if a.arm:
        run(out, a.arm)
    if a.publish:
        publish(out, pathlib.Path(a.publish))


if __name__ == "__main__":
    main()
