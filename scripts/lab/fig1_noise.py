"""Fig. 1 of the paper: a run of the piecewise independent AR process (4).

Sigma = 1, alpha = 0.99, nm-periods of 10 steps, 100 steps; period starts are marked.
Writes scripts/out/fig1_noise.png.

    python scripts/lab/fig1_noise.py [--steps 100 --alpha 0.99 --period 10 --seed 0]
"""

from __future__ import annotations

import argparse
from pathlib import Path


import jax  # noqa: E402
import numpy as np  # noqa: E402

from nmrl.analysis.plots import plt, save  # noqa: E402

from nmrl.paper.noise import piecewise_ar  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--alpha", type=float, default=0.99)
    p.add_argument("--period", type=int, default=10, help="nm-period length l")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "out" / "fig1_noise.png")
    args = p.parse_args(argv)

    xi = np.asarray(piecewise_ar(jax.random.key(args.seed), args.steps, 1, args.alpha, args.period))[:, 0]
    t = np.arange(1, args.steps + 1)  # the paper indexes time from 1

    fig, ax = plt.subplots(figsize=(7.0, 3.2))
    for k, start in enumerate(range(0, args.steps, args.period)):
        seg = slice(start, min(start + args.period, args.steps))
        ax.plot(t[seg], xi[seg], "-o", color="k", ms=2.5, lw=1.2)
        ax.axvline(t[start] - 0.5, color="0.75", lw=0.8, zorder=0)
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_xlim(0.5, args.steps + 0.5)
    ax.set_xlabel("t")
    ax.set_ylabel(r"$\xi_t$")
    ax.set_title(rf"Piecewise independent AR process: $\Sigma=1$, $\alpha={args.alpha}$, "
                 rf"$t_{{k+1}}-t_k\equiv{args.period}$")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save(fig, args.out, dpi=130)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
