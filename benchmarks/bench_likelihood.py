"""Cost of the nm-period likelihood ratio: tridiagonal closed form vs dense solve (Sec. IV).

For l in {1, 2, 5, 10, 30, 100, 300, 1000} and n = 6 (the Half-Cheetah action size) it times,
all jitted, compile (first call) apart from steady state (median of repeats):

* ``tridiagonal``: (Lambda^-1 (x) Sigma^-1) u via ``nmrl.paper.likelihood.lambda_inv_matvec`` -- O(l n);
* ``dense_solve``: Lambda = [alpha^|i-j|] built densely, ``jnp.linalg.solve(Lambda, u)``
  times Sigma^-1 -- O(l^3 + l^2 n);
* ``dense_kron_solve`` (l <= 300): the paper's naive route, solving C y = A - m with
  C = Lambda (x) Sigma dense, -- O((l n)^3);
* ``lr_tridiagonal`` / ``lr_dense``: the full likelihood ratio for the paper's actor
  (31 -> 100 arctan -> 6), ``nmrl.paper.likelihood.likelihood_ratio`` vs the same vjp with the dense solve.

    python benchmarks/bench_likelihood.py            # full run, writes results/benchmarks/likelihood_ratio.{json,png}
    python benchmarks/bench_likelihood.py --quick    # a few seconds, prints only (unless --out)

``run(quick, smoke=False)`` returns the results as a dict (for a ``python -m benchmarks`` harness).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any, Callable

# Multi-threaded OpenBLAS (used by XLA's LAPACK custom calls for the dense solve) spins
# pathologically on a small shared machine (10-20x slower at l >= 300 when the cores are
# busy); pin it to one thread unless the caller chose otherwise. Only effective when this
# module is imported before numpy/jax.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from nmrl.paper.likelihood import lambda_inv_matvec, likelihood_ratio  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "results" / "benchmarks"  # measurements apart from the code
FULL_L = (1, 2, 5, 10, 30, 100, 300, 1000)
QUICK_L = (1, 10, 100)
SMOKE_L = (1, 10)  # the smallest setting: the harness's paths, one or two calls each
N_ACT, N_OBS, N_HID = 6, 31, 100
ALPHA = 0.8
KRON_MAX_L = 300


# --------------------------------------------------------------------------- the contenders


def dense_lambda(l: int, alpha: jax.Array) -> jax.Array:
    """Lambda = [alpha^|i-j|] materialised (l x l)."""
    i = jnp.arange(l)
    return alpha ** jnp.abs(i[:, None] - i[None, :]).astype(jnp.float32)


def tridiagonal(u: jax.Array, alpha: jax.Array, sigma: jax.Array) -> jax.Array:
    return lambda_inv_matvec(u, alpha) / (sigma * sigma)


def dense_solve(u: jax.Array, alpha: jax.Array, sigma: jax.Array) -> jax.Array:
    return jnp.linalg.solve(dense_lambda(u.shape[0], alpha), u) / (sigma * sigma)


def dense_kron_solve(u: jax.Array, alpha: jax.Array, sigma: jax.Array) -> jax.Array:
    C = jnp.kron(dense_lambda(u.shape[0], alpha), jnp.diag(sigma * sigma))
    return jnp.linalg.solve(C, u.reshape(-1)).reshape(u.shape)


def actor_apply(params: dict, S: jax.Array) -> jax.Array:
    """The paper's actor: two-layer perceptron, arctan hidden layer, linear output."""
    return jnp.arctan(S @ params["W1"] + params["b1"]) @ params["W2"] + params["b2"]


def lr_tridiagonal(params: dict, S: jax.Array, A: jax.Array, alpha: jax.Array, sigma: jax.Array) -> dict:
    return likelihood_ratio(actor_apply, params, S, A, alpha, sigma)


def lr_dense(params: dict, S: jax.Array, A: jax.Array, alpha: jax.Array, sigma: jax.Array) -> dict:
    m, vjp = jax.vjp(lambda p: actor_apply(p, S), params)
    return vjp(dense_solve(A - m, alpha, sigma))[0]


# --------------------------------------------------------------------------- timing


def _block(x: Any) -> Any:
    return jax.tree_util.tree_map(lambda a: a.block_until_ready(), x)


def time_jitted(fn: Callable, args: tuple, min_time: float, max_reps: int) -> dict:
    """Compile time (first call, incl. one execution) and median steady-state time."""
    f = jax.jit(fn)
    t0 = time.perf_counter()
    _block(f(*args))
    compile_s = time.perf_counter() - t0
    times: list[float] = []
    total = 0.0
    while len(times) < 3 or (total < min_time and len(times) < max_reps):
        t0 = time.perf_counter()
        _block(f(*args))
        dt = time.perf_counter() - t0
        times.append(dt)
        total += dt
    return {"compile_s": compile_s, "median_s": statistics.median(times), "min_s": min(times),
            "repeats": len(times)}


def machine() -> dict:
    dev = jax.devices()[0]
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "jax_version": jax.__version__,
        "jax_backend": jax.default_backend(),
        "device": getattr(dev, "device_kind", str(dev)),
        "dtype": "float32",
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS"),
        "load_average_at_end": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def run(quick: bool = False, smoke: bool = False) -> dict:
    """Time every contender for every l; returns {'machine', 'config', 'results'}."""
    ls = SMOKE_L if smoke else QUICK_L if quick else FULL_L
    min_time, max_reps = (0.0, 2) if smoke else (0.02, 20) if quick else (0.25, 200)
    rng = np.random.default_rng(0)
    alpha = jnp.float32(ALPHA)
    sigma = jnp.ones((N_ACT,), jnp.float32)
    params = {
        "W1": jnp.asarray(rng.standard_normal((N_OBS, N_HID)), jnp.float32),
        "b1": jnp.asarray(rng.standard_normal(N_HID), jnp.float32),
        "W2": jnp.asarray(0.1 * rng.standard_normal((N_HID, N_ACT)), jnp.float32),
        "b2": jnp.zeros((N_ACT,), jnp.float32),
    }
    results = []
    for l in ls:
        u = jnp.asarray(rng.standard_normal((l, N_ACT)), jnp.float32)
        S = jnp.asarray(rng.standard_normal((l, N_OBS)), jnp.float32)
        A = jnp.asarray(rng.standard_normal((l, N_ACT)), jnp.float32)
        cases: list[tuple[str, Callable, tuple]] = [
            ("tridiagonal", tridiagonal, (u, alpha, sigma)),
            ("dense_solve", dense_solve, (u, alpha, sigma)),
        ]
        if not quick and l <= KRON_MAX_L:
            cases.append(("dense_kron_solve", dense_kron_solve, (u, alpha, sigma)))
        cases += [
            ("lr_tridiagonal", lr_tridiagonal, (params, S, A, alpha, sigma)),
            ("lr_dense", lr_dense, (params, S, A, alpha, sigma)),
        ]
        for name, fn, args in cases:
            r = time_jitted(fn, args, min_time, max_reps)
            results.append({"method": name, "l": l, "n": N_ACT, **r})
            print(f"l={l:5d} {name:17s} compile {r['compile_s'] * 1e3:8.1f} ms   "
                  f"median {r['median_s'] * 1e6:10.1f} us  min {r['min_s'] * 1e6:10.1f} us  "
                  f"({r['repeats']} reps)", flush=True)
    return {
        "benchmark": "nm-period likelihood ratio: (Lambda^-1 (x) Sigma^-1) u, tridiagonal vs dense",
        "machine": machine(),
        "config": {"ls": list(ls), "n": N_ACT, "alpha": ALPHA, "actor": [N_OBS, N_HID, N_ACT],
                   "quick": quick, "smoke": smoke, "steady_state": "median wall time of repeated calls after the first",
                   "compile": "wall time of the first call (trace + compile + one run)"},
        "results": results,
    }


def plot(data: dict, path: Path) -> None:
    from nmrl.analysis.plots import plt, save

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    styles = {"tridiagonal": "C0o-", "dense_solve": "C3s-", "dense_kron_solve": "C1^-",
              "lr_tridiagonal": "C0o-", "lr_dense": "C3s-"}
    panels = (("tridiagonal", "dense_solve", "dense_kron_solve"), ("lr_tridiagonal", "lr_dense"))
    titles = (r"$(\Lambda^{-1}\otimes\Sigma^{-1})u$, n = 6", "full likelihood ratio, actor 31-100-6")
    for ax, methods, title in zip(axes, panels, titles):
        for m in methods:
            rows = [r for r in data["results"] if r["method"] == m]
            if rows:
                ax.plot([r["l"] for r in rows], [r["median_s"] * 1e6 for r in rows], styles[m], label=m)
        rows = [r for r in data["results"] if r["method"] == methods[0]]
        if rows:
            ls = np.array([r["l"] for r in rows], float)
            y_end = rows[-1]["median_s"] * 1e6
            ax.plot(ls, y_end * ls / ls[-1], "k:", lw=1, label=r"$\propto l$")
            dense = [r for r in data["results"] if r["method"] == methods[1]]
            y3 = dense[-1]["median_s"] * 1e6
            ax.plot(ls, y3 * (ls / ls[-1]) ** 3, "k--", lw=1, label=r"$\propto l^3$")
            ax.set_ylim(bottom=0.3 * min(r["median_s"] * 1e6 for r in data["results"] if r["method"] in methods))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("nm-period length l")
        ax.set_ylabel("steady-state time per call [µs]")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    mach = data["machine"]
    fig.suptitle(f"jit, {mach['jax_backend']} ({mach['device']}, {mach['cpu_count']} CPUs), jax {mach['jax_version']}",
                 fontsize=9)
    fig.tight_layout()
    save(fig, path, dpi=120)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="l in {1, 10, 100}, few repeats")
    p.add_argument("--out", type=Path, default=None,
                   help="output stem (default results/benchmarks/likelihood_ratio for a full run; none for --quick)")
    args = p.parse_args(argv)
    data = run(args.quick)
    stem = args.out if args.out is not None else (None if args.quick else OUT / "likelihood_ratio")
    if stem is not None:
        stem.with_suffix(".json").write_text(json.dumps(data, indent=2) + "\n")
        plot(data, stem.with_suffix(".png"))
        print(f"wrote {stem.with_suffix('.json')} and {stem.with_suffix('.png')}")
    by = {(r["method"], r["l"]): r["median_s"] for r in data["results"]}
    for l in data["config"]["ls"]:
        if ("dense_solve", l) in by:
            ratio = by[("dense_solve", l)] / by[("tridiagonal", l)]
            print(f"l={l:5d}: dense_solve / tridiagonal = {ratio:8.1f}x")


if __name__ == "__main__":
    main()
