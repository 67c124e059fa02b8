"""Run every nmrl benchmark, write one JSON file, a markdown table and a throughput figure.

    python -m benchmarks                 # full run   -> results/benchmarks/results.json, throughput.png
    python -m benchmarks --quick         # ~1 minute  -> results/benchmarks/results_quick.json, throughput_quick.png
    python -m benchmarks --only env,sweep --out /tmp/r.json
    python -m benchmarks --smoke         # every section at its smallest setting: checks that the
                                         # harness runs (tests/test_benchmarks.py); writes nothing

Benchmarks (each a module ``benchmarks/bench_<name>.py`` with ``run(quick, smoke=False) -> dict``;
``smoke`` is the smallest setting, a module without that parameter is run quick):

* ``env``        MJX physics steps/s vs MuJoCo C (``mujoco.rollout``), MJX on 1 and 2 CPU devices,
                 C with 1 and 2 threads (benchmarks/bench_env.py; MJX in subprocesses with a timeout);
* ``learning``   training chunk vs environment-only scan, same batch (benchmarks/bench_learning.py);
* ``likelihood`` tridiagonal vs dense likelihood ratio (benchmarks/bench_likelihood.py);
* ``sweep``      the paper's 24-point sweep with learning: the layout of ``nmrl sweep`` (points over
                 every core, one at a time per core) vs one vmap on one device vs MuJoCo C (bench_sweep.py);
* ``scaling``    training chunk on 1 vs 2 CPU devices, the sweep's shard_map path (bench_scaling.py);
* ``distributed`` ``nmrl train`` as 2 processes (jax.distributed, 1 device each) vs 1 process with
                 2 devices, end to end through the CLI (bench_distributed.py);
* ``baseline``   wall time per 10^7 control steps, Brax PPO (``nmrl baseline ppo``) vs the
                 nm-period actor-critic (``nmrl train``), both on 2 devices (bench_baseline.py; needs Brax).
* ``ppo``        native PPO vs Brax PPO at the Brax settings, control steps/s with learning, and the
                 native iteration's profile (bench_ppo.py; the Brax half needs Brax).
* ``physics_c``  ``--physics c``: the C env in the program vs ``mujoco.batch`` alone, the 24-point sweep
                 with learning on C vs MJX vs MuJoCo C alone, native PPO on C vs MJX (bench_physics_c.py).
* ``grad_chunks`` PPO at 2.5 ms in the second exploration study's grid layout, each minibatch's gradient
                 in parts (``--grad-chunks``) vs at once (bench_grad_chunks.py).

Every comparison is a ratio measured within one run, the contenders interleaved, so that a
background load affects both alike; absolute numbers are reported beside the machine description
and the load average. Compile time is always reported apart from steady-state time; XLA's
persistent compile cache (``JAX_COMPILATION_CACHE_DIR``, default ``~/.cache/nmrl/xla``) is used, so a
second run (and a quick run after a full one: the quick shapes are a subset of the full ones)
skips most of the compilation.

The JSON file has the same top-level keys in quick and full mode. With ``--only`` the sections not
run are kept from the existing output file (if any), otherwise they are ``null``.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import importlib
import inspect
import json
import os
import pathlib
import statistics
import sys
import time
import traceback

# Before JAX / numpy are imported (here and in the subprocesses, which inherit the environment).
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/nmrl/xla"))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see benchmarks/bench_likelihood.py

from benchmarks.report import plot, summary, table  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
#: where the measurements go, apart from the code that takes them (results/README.md)
OUT = ROOT / "results" / "benchmarks"

SECTIONS = ("env", "learning", "likelihood", "sweep", "scaling", "distributed", "baseline", "explore", "ppo",
            "physics_c", "grad_chunks")
SIZES = ("full", "quick", "smoke")
TOP_KEYS = ("meta", "machine", *SECTIONS, "summary")

# env: control steps (batch x T) per timed MJX call, the same in quick and full mode so that a quick
# run hits the compile cache of a full run (T = max(4096 // B, 8))
ENV_STEPS_PER_CALL = 4096
ENV_FULL_BATCHES = [64, 256, 1024]
ENV_QUICK_BATCHES = [64]
ENV_SMOKE = {"batches": [8], "steps_per_call": 64}  # T = 8: the harness's paths, not a measurement


# ------------------------------------------------------------------------------- sections


def bench_env_section(size: str) -> dict:
    """MJX (1 device, 2 devices shard_map) vs MuJoCo C (1, 2 threads); C measured before, between
    and after the MJX subprocesses, and its median taken, so C and MJX see the same load."""
    from benchmarks import bench_env

    quick = size != "full"
    sizes = ENV_SMOKE["batches"] if size == "smoke" else ENV_QUICK_BATCHES if quick else ENV_FULL_BATCHES
    steps_per_call = ENV_SMOKE["steps_per_call"] if size == "smoke" else ENV_STEPS_PER_CALL
    rep = 1 if quick else 3
    timeout = 600  # per MJX worker: catches a hang; a compile on a loaded 2-core machine takes minutes
    t0 = time.perf_counter()
    threads = sorted({1, 2, os.cpu_count() or 1})
    c_runs, mjx, load = [], {}, {}
    c_runs.append(bench_env.c_rollout(sizes, steps_per_call, threads, repeats=rep))
    load["before"] = list(os.getloadavg())
    mjx["1dev_single"] = bench_env.mjx_subprocess(sizes, "single", 1, steps_per_call, rep, timeout=timeout)
    c_runs.append(bench_env.c_rollout(sizes, steps_per_call, threads, repeats=rep))
    load["between"] = list(os.getloadavg())
    mjx["2dev_shard_map"] = bench_env.mjx_subprocess(sizes, "shard_map", 2, steps_per_call, rep,
                                                      timeout=timeout)
    c_runs.append(bench_env.c_rollout(sizes, steps_per_call, threads, repeats=rep))
    load["after"] = list(os.getloadavg())
    c = []
    for nt in threads:
        for B in sizes:
            vals = [r["physics_steps_per_s"] for run in c_runs for r in run if r["batch"] == B and r["nthread"] == nt]
            c.append({"batch": B, "nthread": nt, "physics_steps_per_s": statistics.median(vals),
                      "physics_steps_per_s_runs": vals})
    ratios = {}
    for B in sizes:
        mj = {k: r["physics_steps_per_s"] for k, v in mjx.items() for r in v.get("results", []) if r["batch"] == B}
        cc = {f"c_{r['nthread']}thread": r["physics_steps_per_s"] for r in c if r["batch"] == B}
        if not mj:
            continue
        ratios[str(B)] = {
            **{f"{a}/{b}": mj[a] / cc[b] for a in mj for b in cc},
            "best_mjx/best_c": max(mj.values()) / max(cc.values()),
        }
    best = [r["best_mjx/best_c"] for r in ratios.values()]
    return {
        "benchmark": "Half-Cheetah physics steps/s: MJX (jit scan of vmap(env.step)) vs MuJoCo C rollout",
        "quick": quick,
        "size": size,
        "config": {"batches": sizes, "control_steps_per_call": steps_per_call, "repeats": rep,
                   "c_threads": threads, "mjx_statistic": "best of repeats (bench_env.py)",
                   "c_statistic": "median over 3 runs (before, between, after the MJX runs) of the best of repeats",
                   "timeout_s": timeout},
        "mjx": mjx, "c": c, "c_runs": c_runs,
        "ratio_mjx_over_c": ratios,
        "goal": "MJX >= 0.75 x MuJoCo C physics steps/s",
        "goal_met": bool(best) and min(best) >= 0.75,
        "best_ratio_range": [min(best), max(best)] if best else None,
        "load_avg": load,
        "wall_s": time.perf_counter() - t0,
    }


def errors_in(tree, path: str = "") -> list[str]:
    """Every ``error`` entry (and a true ``failed`` flag) in a section's result, as "path: message"."""
    out = []
    if isinstance(tree, dict):
        for k, v in tree.items():
            if k == "error" or (k == "failed" and v is True):
                out.append(f"{path or '.'}: {str(v)[:200]}")
            else:
                out += errors_in(v, f"{path}.{k}")
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            out += errors_in(v, f"{path}[{i}]")
    return out


def run_section(name: str, size: str) -> dict:
    """Run one section at ``size`` (one of SIZES): ``env`` here, every other one as
    ``benchmarks.bench_<name>.run(quick, smoke=...)``."""
    if size not in SIZES:
        raise ValueError(f"size={size!r}: one of {SIZES}")
    if name == "env":
        return bench_env_section(size)
    if name not in SECTIONS:
        raise ValueError(f"unknown benchmark {name!r}; one of {SECTIONS}")
    mod = importlib.import_module(f"benchmarks.bench_{name}")
    smoke = {"smoke": True} if size == "smoke" and "smoke" in inspect.signature(mod.run).parameters else {}
    return mod.run(size != "full", **smoke)


# ------------------------------------------------------------------------------- machine


def machine() -> dict:
    """bench_env's machine description plus memory, backend and the compile-cache state."""
    import jax

    from benchmarks import bench_env

    m = bench_env.machine()
    mem = None
    try:
        mem = int(next(l.split()[1] for l in open("/proc/meminfo") if l.startswith("MemTotal"))) / 2**20
    except (OSError, StopIteration, ValueError):
        pass
    cache = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    entries = len(os.listdir(cache)) if cache and os.path.isdir(cache) else 0  # > 0: compile_s may be cache hits
    m.update({"mem_gib": mem, "jax_backend": jax.default_backend(), "load_avg_at_start": list(m["load_avg_at_start"]),
              "compile_cache": cache, "compile_cache_entries_at_start": entries})
    return m


# ------------------------------------------------------------------------------- main


def _atomic_write(path: pathlib.Path, text: str) -> None:
    from nmrl.runs.store import atomic_write_text

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sizes = ap.add_mutually_exclusive_group()
    sizes.add_argument("--quick", action="store_true", help="small batches, few repeats (~1 minute with a warm cache)")
    sizes.add_argument("--smoke", action="store_true",
                      help="every section at its smallest setting, to check that the harness runs (numbers "
                           "meaningless); writes only --out, if given, and no figure")
    ap.add_argument("--out", type=pathlib.Path, default=None,
                    help="JSON output (default results/benchmarks/results.json; --quick: "
                         "results/benchmarks/results_quick.json)")
    ap.add_argument("--only", default=",".join(SECTIONS),
                    help=f"comma-separated subset of {','.join(SECTIONS)} (default: all)")
    ap.add_argument("--no-plot", action="store_true", help="do not write the figure")
    args = ap.parse_args(argv)
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    bad = [s for s in only if s not in SECTIONS]
    if bad or not only:
        print(f"--only: unknown benchmark(s) {bad}; choose from {','.join(SECTIONS)}", file=sys.stderr)
        return 2
    size = "smoke" if args.smoke else "quick" if args.quick else "full"
    out = args.out if args.out or args.smoke else OUT / ("results_quick.json" if args.quick else "results.json")
    png = None if args.smoke or args.no_plot else (
        out.with_name("throughput_quick.png" if args.quick else "throughput.png") if args.out is None
        else out.with_suffix(".png"))

    import jax  # may already be imported (``nmrl bench``): then the environment variable came too late

    if not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])

    t0 = time.perf_counter()
    res: dict = {k: None for k in TOP_KEYS}
    if set(only) != set(SECTIONS) and out is not None and out.exists():  # keep the sections not re-run
        try:
            old = json.loads(out.read_text())
            res.update({k: old.get(k) for k in SECTIONS})
        except (OSError, ValueError):
            pass
    res["machine"] = machine()
    failed = []
    for name in only:
        print(f"== {name}", file=sys.stderr, flush=True)
        t1 = time.perf_counter()
        try:
            with contextlib.redirect_stdout(sys.stderr):  # progress lines; stdout is the table
                res[name] = run_section(name, size)
            inner = errors_in(res[name])
            if inner:  # a contender failed or hung inside the section: reported, and the exit status says so
                failed.append(name)
                print(f"== {name}: failed inside: {'; '.join(inner)}", file=sys.stderr, flush=True)
        except Exception as e:  # noqa: BLE001 -- one broken benchmark must not lose the others
            failed.append(name)
            res[name] = {"error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()[-3000:]}
            print(res[name]["traceback"], file=sys.stderr, flush=True)
        print(f"== {name}: {time.perf_counter() - t1:.1f} s", file=sys.stderr, flush=True)
    res["machine"]["load_avg_at_end"] = list(os.getloadavg())
    res["meta"] = {"quick": size != "full", "size": size, "sections_run": only, "failed": failed,
                   "command": "python -m benchmarks" + ("" if size == "full" else f" --{size}")
                   + ("" if set(only) == set(SECTIONS) else f" --only {','.join(only)}"),
                   "date": datetime.datetime.now().isoformat(timespec="seconds"),
                   "wall_s": time.perf_counter() - t0}
    res["summary"] = summary(res)
    if out is not None:
        _atomic_write(out, json.dumps(res, indent=1, default=float) + "\n")
    md = table(res)
    print(md)
    m = res["machine"]
    print(f"\n{m['cpu']}, {m['cpu_count']} cores; load avg {m['load_avg_at_start'][0]:.2f} at start, "
          f"{m['load_avg_at_end'][0]:.2f} at end; wall {res['meta']['wall_s']:.0f} s"
          + (f"; wrote {out}" if out is not None else ""))
    if png is not None:
        try:
            plot(res, png)
            print(f"wrote {png}")
        except Exception:  # noqa: BLE001
            traceback.print_exc()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
