"""Wall time per 10^7 control steps on this machine: Brax PPO (``nmrl baseline ppo``) vs the paper's
nm-period actor-critic (``nmrl train``, Table II), both on every core (2 CPU devices), end to end.

* PPO: the baseline's own settings (nmrl/experiments/baseline_ppo.py: 64 environments, 327,680
  control steps per iteration, Adam over 8 epochs x 32 minibatches), ``--max-iterations`` K; the
  steady-state speed is the median of the per-iteration ``steps_per_s`` in metrics.jsonl without
  the first two iterations (both compile: ``WARMUP``); their extra time is reported as compile time.
* Actor-critic: ``nmrl train --preset paper --l 10`` with ``AC_ENVS`` environments (32 per device:
  the per-point layout of scripts/run/fig3_paper.sh is 32 environments on one device, here one run
  uses both), chunks of ``AC_CHUNK`` steps; median of the per-chunk ``steps_per_s`` without chunk 1.

The contenders alternate (PPO, AC, PPO, ...); the ratio is the median over rounds of the per-round
ratio. Needs Brax (``pip install -e '.[brax]'``); without it the section says so.

``run(quick, smoke=False) -> dict`` (``smoke``: Brax PPO at 8 environments and tiny batches for 3
iterations, the actor-critic for two 10-step chunks; the harness's paths only);
``python -m benchmarks.bench_baseline [--quick]`` prints it.
"""

from __future__ import annotations

import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks import main, paired_rounds, subprocess_env

AC_ENVS = 64
AC_CHUNK = 500
#: PPO iterations that compile: the first, and the second (Brax's pmapped epoch is compiled again
#: once its inputs are its own outputs: seen with jax_log_compiles)
WARMUP = 2
#: the smallest setting: PPO's options (the iterations must exceed WARMUP) and the actor-critic's
SMOKE = {"ppo": ["--num-envs", "8", "--batch-size", "8", "--num-minibatches", "2", "--unroll-length", "4"],
         "ppo_iterations": WARMUP + 1, "ac_envs": 8, "ac_chunk": 10, "ac_chunks": 2}


def _rows(out: pathlib.Path) -> list[dict]:
    return [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]


def _run(cmd: list[str], timeout: float) -> str | None:
    try:
        p = subprocess.run(cmd, env=subprocess_env(), capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return f"timeout after {timeout:.0f} s"
    return None if p.returncode == 0 else f"exit status {p.returncode}: {p.stderr[-800:]}"


def ppo_run(iterations: int, timeout: float, options: tuple[str, ...] = ()) -> dict:
    with tempfile.TemporaryDirectory(prefix="nmrl_bench_ppo_") as tmp:
        out = pathlib.Path(tmp) / "ppo"
        t0 = time.perf_counter()
        err = _run([sys.executable, "-m", "nmrl.cli", "baseline", "ppo", "--out", str(out), "--devices", "2",
                    "--max-iterations", str(iterations), "--quiet", *options], timeout)
        if err:
            return {"error": err}
        rows = [r for r in _rows(out) if r["step"] > 0]
        rates = [r["steps_per_s"] for r in rows[WARMUP:]]
        steady = statistics.median(rates)
        spi = rows[0]["step"]
        return {"iterations": len(rows), "control_steps_per_iteration": spi, "control_steps_per_s": steady,
                "per_iteration_steps_per_s": [r["steps_per_s"] for r in rows],
                "compile_s": sum(r["wall_s"] for r in rows[:WARMUP]) - WARMUP * spi / steady,
                "wall_s": time.perf_counter() - t0}


def ac_run(chunks: int, timeout: float, envs: int = AC_ENVS, chunk: int = AC_CHUNK) -> dict:
    with tempfile.TemporaryDirectory(prefix="nmrl_bench_ac_") as tmp:
        out = pathlib.Path(tmp) / "ac"
        t0 = time.perf_counter()
        err = _run([sys.executable, "-m", "nmrl.cli", "train", "--preset", "paper", "--l", "10", "--num-envs",
                    str(envs), "--chunk-steps", str(chunk), "--steps", str(chunk * chunks), "--devices",
                    "2", "--quiet", "--out", str(out)], timeout)
        if err:
            return {"error": err}
        rows = _rows(out)
        rates = [r["steps_per_s"] for r in rows[1:]]
        return {"chunks": len(rows), "control_steps_per_s": statistics.median(rates),
                "per_chunk_steps_per_s": rates, "wall_s": time.perf_counter() - t0}


def run(quick: bool = False, smoke: bool = False) -> dict:
    from nmrl.adapters import brax_env

    if not brax_env.HAVE_BRAX:
        return {"benchmark": "baseline", "skipped": "Brax is not installed (pip install -e '.[brax]')"}
    rounds, iters, chunks = (1, 3, 4) if quick else (2, 4, 8)
    ppo_opts, envs, chunk = (), AC_ENVS, AC_CHUNK
    if smoke:
        iters, chunks, ppo_opts = SMOKE["ppo_iterations"], SMOKE["ac_chunks"], tuple(SMOKE["ppo"])
        envs, chunk = SMOKE["ac_envs"], SMOKE["ac_chunk"]
    t0 = time.perf_counter()
    runs, ratios = paired_rounds(rounds, ("ppo", lambda: ppo_run(iters, 3600, ppo_opts)),
                                 ("actor_critic", lambda: ac_run(chunks, 1800, envs, chunk)))
    ok = lambda k: [r["control_steps_per_s"] for r in runs[k] if "error" not in r]  # noqa: E731
    med = {k: statistics.median(ok(k)) if ok(k) else None for k in runs}
    out = {
        "benchmark": "wall time per 10^7 control steps: Brax PPO (nmrl baseline ppo) vs nm-period actor-critic "
                     "(nmrl train, paper preset, l = 10), both on 2 CPU devices",
        "quick": quick, "smoke": smoke,
        "config": {"rounds": rounds, "ppo_iterations": iters, "ppo_options": list(ppo_opts), "ac_envs": envs,
                   "ac_chunk_steps": chunk,
                   "ac_chunks": chunks},
        "runs": runs,
        "ppo_over_actor_critic_speed": statistics.median(ratios) if ratios else None,
        "hours_per_1e7_steps": {k: (1e7 / v / 3600 if v else None) for k, v in med.items()},
        "load_avg": list(os.getloadavg()),
        "wall_s": time.perf_counter() - t0,
    }
    r = out["ppo_over_actor_critic_speed"]
    print(f"baseline: PPO / actor-critic control steps per s = {r:.2f}x" if r else "baseline: failed",
          file=sys.stderr, flush=True)
    return out


if __name__ == "__main__":
    main(run)
