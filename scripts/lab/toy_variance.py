"""Sec. II toy: REINFORCE variance vs time step, stationary policy vs nm-periods.

For each delta_t the script draws ``--samples`` episodes of the 1-D velocity toy and
reports the Monte Carlo variance of

* the stationary episodic-REINFORCE estimator, against the paper's formula (1), and
* the same estimator with piecewise AR noise (4) in nm-periods of a fixed duration
  (``--duration`` s, l = duration/delta_t steps; per-step alpha = rho**(delta_t/tau) so the
  correlation per second is fixed) and the nm-period likelihood ratio, against the
  closed form of ``nmrl.paper.toy.nm_variance``.

The stationary variance grows like 1/delta_t; the nm-period one stays bounded.
Writes scripts/out/toy_variance.png and scripts/out/toy_variance.md.

    python scripts/lab/toy_variance.py [--samples 20000]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path


import jax  # noqa: E402
import numpy as np  # noqa: E402

from nmrl.analysis.plots import plt, save  # noqa: E402

from nmrl.paper import toy  # noqa: E402

DELTAS = (0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--samples", type=int, default=20_000, help="episodes per delta_t and estimator")
    p.add_argument("--theta", type=float, default=1.0, help="policy parameter (mean acceleration)")
    p.add_argument("--baseline", type=float, default=0.0, help="REINFORCE baseline c")
    p.add_argument("--sigma-a", type=float, default=1.0, help="action standard deviation sigma_a")
    p.add_argument("--sigma-y", type=float, default=0.5, help="reward noise standard deviation sigma_y")
    p.add_argument("--duration", type=float, default=0.1, help="nm-period duration in seconds")
    p.add_argument("--rho", type=float, default=0.8, help="noise correlation over --tau seconds")
    p.add_argument("--tau", type=float, default=0.02, help="time over which the correlation is --rho")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "out")
    return p.parse_args(argv)


def run(args: argparse.Namespace) -> list[dict]:
    """Monte Carlo + closed forms for every delta_t; one dict per row."""
    rows = []
    key = jax.random.key(args.seed)
    common = dict(theta=args.theta, c=args.baseline, sigma_a=args.sigma_a, sigma_y=args.sigma_y)
    for j, dt in enumerate(DELTAS):
        k_st, k_nm = jax.random.split(jax.random.fold_in(key, j))
        l = toy.nm_period_length(dt, args.duration)
        alpha = toy.alpha_per_step(dt, args.rho, args.tau)
        g_st = np.asarray(toy.sample_stationary(k_st, dt, args.samples, **common))
        g_nm = np.asarray(toy.sample_nm(k_nm, dt, args.samples, l, alpha, **common))
        m_st, sm_st, v_st, sv_st = toy.variance_with_se(g_st)
        m_nm, sm_nm, v_nm, sv_nm = toy.variance_with_se(g_nm)
        rows.append(
            dict(
                delta_t=dt,
                T=toy.num_steps(dt),
                l=l,
                alpha=alpha,
                mean_st=m_st,
                se_mean_st=sm_st,
                var_st=v_st,
                se_var_st=sv_st,
                formula1=toy.stationary_variance(dt, **common),
                mean_nm=m_nm,
                se_mean_nm=sm_nm,
                var_nm=v_nm,
                se_var_nm=sv_nm,
                formula_nm=toy.nm_variance(dt, l, alpha, **common),
            )
        )
    return rows


def markdown(rows: list[dict], args: argparse.Namespace) -> str:
    head = (
        f"Sec. II toy, {args.samples} episodes per cell; theta={args.theta}, c={args.baseline}, "
        f"sigma_a={args.sigma_a}, sigma_y={args.sigma_y}; nm-periods of {args.duration} s, "
        f"alpha = {args.rho}^(delta_t/{args.tau}). Values are mean ± SE (true gradient = 1) "
        "and variance ± SE.\n\n"
        "| delta_t | T | l | alpha | stationary mean | stationary Var (MC) | formula (1) "
        "| nm mean | nm Var (MC) | nm closed form |\n"
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
    )
    lines = [
        f"| {r['delta_t']:g} | {r['T']} | {r['l']} | {r['alpha']:.4f} "
        f"| {r['mean_st']:.3f} ± {r['se_mean_st']:.3f} | {r['var_st']:.1f} ± {r['se_var_st']:.1f} "
        f"| {r['formula1']:.1f} | {r['mean_nm']:.3f} ± {r['se_mean_nm']:.3f} "
        f"| {r['var_nm']:.2f} ± {r['se_var_nm']:.2f} | {r['formula_nm']:.2f} |"
        for r in rows
    ]
    return head + "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path, args: argparse.Namespace) -> None:
    dts = np.array([r["delta_t"] for r in rows])
    fine = np.geomspace(dts.min(), dts.max(), 100)
    common = dict(theta=args.theta, c=args.baseline, sigma_a=args.sigma_a, sigma_y=args.sigma_y)
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    ax.plot(fine, [toy.stationary_variance(d, **common) for d in fine], "C0-", label="formula (1), stationary")
    ax.errorbar(dts, [r["var_st"] for r in rows], yerr=[2 * r["se_var_st"] for r in rows], fmt="C0o",
                label="Monte Carlo, stationary")
    ax.plot(dts, [r["formula_nm"] for r in rows], "C1--", label=f"closed form, nm-periods of {args.duration} s")
    ax.errorbar(dts, [r["var_nm"] for r in rows], yerr=[2 * r["se_var_nm"] for r in rows], fmt="C1s",
                label="Monte Carlo, nm-periods")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.invert_xaxis()
    ax.set_xlabel("time step δ [s]")
    ax.set_ylabel("Var ĝ  (REINFORCE estimator)")
    ax.set_title("Sec. II toy: gradient-estimator variance vs time step")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save(fig, path, dpi=120)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = run(args)
    md = markdown(rows, args)
    (args.out / "toy_variance.md").write_text(md)
    plot(rows, args.out / "toy_variance.png", args)
    print(md)
    print(f"wrote {args.out / 'toy_variance.md'} and {args.out / 'toy_variance.png'} "
          f"in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
