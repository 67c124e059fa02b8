"""``nmrl train`` as 2 processes (1 CPU device each, jax.distributed over 127.0.0.1) vs 1 process
with 2 devices: the same mesh size, the same program but for where the psum of the summed update
runs (gloo over TCP between processes vs in-process), measured end to end through the CLI.

Each contender is a real ``nmrl train`` run (the paper preset, ``NUM_ENVS`` environments, chunks
of ``CHUNK_STEPS`` control steps) into a fresh run directory; its steady-state speed is the median
of the per-chunk ``steps_per_s`` in metrics.jsonl (chunk 1 left out: its first call), its compile
time the "compiled the training chunk in X s" line (reported apart; the persistent compile cache
may make it a cache hit). The contenders alternate (2 processes, 1 process, 2 processes, ...) and the
ratio is the median over rounds of the per-round ratio, so a background load affects both alike.

``run(quick, smoke=False) -> dict`` (``smoke``: 8 environments, two 10-step chunks, one round);
``python -m benchmarks.bench_distributed [--quick]`` prints it.
"""

from __future__ import annotations

import json
import os
import pathlib
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks import main, paired_rounds, subprocess_env

NUM_ENVS = 64
CHUNK_STEPS = 100
SMOKE = {"num_envs": 8, "chunk_steps": 10, "chunks": 2, "hidden": 8}
_COMPILED = re.compile(r"compiled the training chunk .* in ([\d.]+) s")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one_run(processes: int, steps: int, timeout: float, options: list[str]) -> dict:
    """One ``nmrl train [options]`` of ``steps`` control steps as ``processes`` processes (1: with 2 devices)."""
    with tempfile.TemporaryDirectory(prefix="nmrl_bench_dist_") as tmp:
        out = pathlib.Path(tmp) / "run"
        base = [sys.executable, "-m", "nmrl.cli", "train", *options, "--steps", str(steps), "--out", str(out)]
        if processes == 1:
            cmds = [base + ["--devices", "2"]]
        else:
            port = _port()
            cmds = [base + ["--devices", "1", "--coordinator", f"127.0.0.1:{port}", "--num-processes",
                            str(processes), "--process-id", str(i), "--dist-timeout", "120"] for i in range(processes)]
        t0 = time.perf_counter()
        ps = [subprocess.Popen(c, env=subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for c in cmds]
        try:
            res = [p.communicate(timeout=timeout) for p in ps]
        except subprocess.TimeoutExpired:
            for p in ps:
                p.kill()
            return {"processes": processes, "error": f"timeout after {timeout:.0f} s"}
        wall = time.perf_counter() - t0
        if any(p.returncode for p in ps):
            return {"processes": processes, "error": f"exit status {[p.returncode for p in ps]}",
                    "stderr_tail": res[0][1][-1500:]}
        rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
        m = _COMPILED.search(res[0][1])
        rates = [r["steps_per_s"] for r in rows[1:]]
        return {"processes": processes, "devices_per_process": 2 if processes == 1 else 1, "chunks": len(rows),
                "compile_s": float(m.group(1)) if m else None, "control_steps_per_s": statistics.median(rates),
                "per_chunk_steps_per_s": rates, "wall_s": wall}


def run(quick: bool = False, smoke: bool = False) -> dict:
    rounds = 1 if quick else 3
    num_envs, chunk_steps = (SMOKE["num_envs"], SMOKE["chunk_steps"]) if smoke else (NUM_ENVS, CHUNK_STEPS)
    steps = chunk_steps * (SMOKE["chunks"] if smoke else 4 if quick else 8)
    options = ["--num-envs", str(num_envs), "--chunk-steps", str(chunk_steps)]
    if smoke:
        options += ["--hidden-actor", str(SMOKE["hidden"]), "--hidden-critic", str(SMOKE["hidden"])]
    timeout = 900
    t0 = time.perf_counter()
    runs, ratios = paired_rounds(rounds, ("two_processes_one_device_each", lambda: one_run(2, steps, timeout, options)),
                                 ("one_process_two_devices", lambda: one_run(1, steps, timeout, options)))
    out = {
        "benchmark": "nmrl train: 2 processes x 1 CPU device (jax.distributed, gloo) vs 1 process x 2 devices",
        "quick": quick, "smoke": smoke,
        "config": {"num_envs": num_envs, "chunk_steps": chunk_steps, "steps": steps, "rounds": rounds,
                   "options": options,
                   "preset": "paper", "statistic": "median over rounds of the per-round ratio of the runs' "
                   "median per-chunk control steps/s (first chunk left out)"},
        "runs": runs,
        "two_processes_over_one_process": statistics.median(ratios) if ratios else None,
        "failed": len(ratios) < rounds,
        "load_avg": list(os.getloadavg()),
        "wall_s": time.perf_counter() - t0,
    }
    r = out["two_processes_over_one_process"]
    print(f"distributed: 2 processes / 1 process with 2 devices = {r:.2f}x" if r else "distributed: failed",
          file=sys.stderr, flush=True)
    return out


if __name__ == "__main__":
    main(run)
