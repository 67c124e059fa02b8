"""Period-wise nm-periods in PPO at 20 ms (issue: the NMp arm of study 2 never learned): the same
cells as study 2's grid (nmrl/experiments/exploration2_cells.py: 64 environments, 16 iterations,
C physics at a 2.5 ms timestep, trials of 5 s, the deterministic endpoint) for seeds 0-1, with NMp's
noise scale below the screen's choice, with the noise's covariance independent of the policy
(``--learn-std false``: std_theta = 1, the paper's C_k), with the clip of a period's ratio widened to
a trust region per second (``--clip-eps`` 0.52 = 0.3 sqrt(3) for 3-step periods), and with the noise
nearly white inside the periods (``--corr-time-s`` 0.01), so that each can be set against study 2's
NMp(20) (sigma 1: every run stands) and W(20) (walks) of the same seeds.

    python scripts/lab/nmp_diagnosis.py --out runs/nmp_diagnosis      # runs what is missing, prints rows
    python scripts/lab/nmp_diagnosis.py --out runs/nmp_diagnosis --publish results/exploration2/diagnosis

``--noise-scales`` then rolls out the policies of :data:`NOISE_CELLS` with their own noise times k
(0, 0.25, 0.5, 1; study 2's check, nmrl/experiments/exploration2_noise.py, at its endpoint's
settings) into ``noise_scales.csv`` beside rows.csv: is the walking carried by the noise?
"""

from __future__ import annotations

import argparse
import pathlib
import shutil

from nmrl.experiments import exploration2_diagnosis, kit
from nmrl.experiments.exploration2_cells import ARMS, ENDPOINT, GRID_ITERATIONS, cell

SEEDS = 2
VARIANTS = {
    "nmp_sigma0.4": {"sigma": 0.4},
    "nmp_sigma0.16": {"sigma": 0.16},
    "nmp_sigma1_fixed_std": {"sigma": 1.0, "learn_std": False},
    # a trust region per second: a period of 0.06 s is 3 control steps, so the clip of its ratio is
    # widened by sqrt(3) (KL grows as the log-ratio squared): NMp's KL per second then matches white's
    "nmp_sigma1_clip0.52": {"sigma": 1.0, "clip_eps": 0.52},
    # the noise nearly white (AR coefficient exp(-0.02 / 0.01) = 0.14 per step) with the period-wise
    # ratio kept: separates learning on periods as wholes from the noise's correlation
    "nmp_sigma1_corr0.01": {"sigma": 1.0, "corr_time_s": 0.01},
}


#: the variants whose policies the noise-scale check rolls out
NOISE_CELLS = ("dt0.02/nmp_sigma1_clip0.52", "dt0.02/nmp_sigma1_corr0.01")


def noise_scales(out: pathlib.Path) -> list[dict]:
    """Each point of :data:`NOISE_CELLS` at its endpoint's step with its noise times k (module docstring)."""
    import json

    import numpy as np

    from nmrl.analysis import endpoint
    from nmrl.experiments.exploration2_noise import COLUMNS, NOISE_CSV, NOISE_SCALES
    from nmrl.runs import checkpoint, store

    rows = []
    for cell in NOISE_CELLS:
        for point in sorted((out / cell / "points").iterdir()):
            step = int(json.loads((point / kit.ENDPOINT).read_text())["step"])
            _, config, params = checkpoint.restore_params(point, step)
            for k in NOISE_SCALES:
                e = endpoint.noisy_endpoint(config, params, k, seconds=ENDPOINT.seconds, rollouts=ENDPOINT.rollouts,
                                            start_noise=ENDPOINT.start_noise, seed=ENDPOINT.seed)
                rows.append({"cell": cell, "point": point.name, "seed": int(config.budget.seed), "step": step,
                             "noise_scale": k, "reward_per_s": e["reward_per_s"],
                             "forward_speed": float(np.mean(e["forward_speed"]))})
    store.write_csv(out / NOISE_CSV, COLUMNS, rows)
    return rows


def cells() -> tuple[kit.Cell, ...]:
    return tuple(cell(f"dt0.02/{name}", 0.02, GRID_ITERATIONS, {**ARMS["nmp"], **extra}, seeds=SEEDS, seed0=0,
                      run_options={"group": SEEDS}) for name, extra in VARIANTS.items())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--publish", metavar="DEST", help="then copy the cells' rows and continuation files to DEST")
    ap.add_argument("--noise-scales", action="store_true", help="then the noise-scale check (module docstring)")
    a = ap.parse_args()
    study = kit.Study(name="nmp_diagnosis", cells=cells(), endpoint=ENDPOINT)
    kit.run(study, a.out)
    if a.noise_scales:
        for r in noise_scales(pathlib.Path(a.out)):
            print(r["cell"], r["point"], f"k {r['noise_scale']}: {r['reward_per_s']:.1f} /s at {r['forward_speed']:.2f} m/s")
    if a.publish:
        kit.publish(study, a.out, a.publish)
        if (pathlib.Path(a.out) / "noise_scales.csv").is_file():
            shutil.copy2(pathlib.Path(a.out) / "noise_scales.csv", pathlib.Path(a.publish) / "noise_scales.csv")
    tr = exploration2_diagnosis.trust_region(pathlib.Path(a.out), tuple(c.name for c in cells()))
    for cell, t in exploration2_diagnosis.summary(tr).items():
        print(cell, f"iterations 2-{t['iterations'] + 1}: KL {t['kl_per_s']:.2f} per s, {t['clip_frac']:.3f} clipped")
    for r in kit.rows(study, pathlib.Path(a.out)):
        print(r["cell"], r["point"], f"det {float(r['det_reward_per_s']):.1f} /s at {float(r['det_forward_speed']):.2f} m/s;"
              f" exploring {float(r['avg_reward_per_s']):.1f} /s at {float(r['forward_speed']):.2f} m/s")


if __name__ == "__main__":
    main()
