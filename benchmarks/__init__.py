"""Benchmarks of nmrl: ``python -m benchmarks [--quick]`` (see benchmarks/__main__.py)."""

import os
from collections.abc import Callable


def subprocess_env() -> dict:
    """The environment for a benchmark's ``nmrl`` subprocess: CPU JAX, the persistent compile cache,
    no inherited XLA_FLAGS (the command sets its own device count)."""
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    env["JAX_PLATFORMS"] = "cpu"
    env.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/nmrl/xla"))
    return env


def paired_rounds(rounds: int, first: tuple[str, Callable[[], dict]],
                  second: tuple[str, Callable[[], dict]]) -> tuple[dict, list]:
    """Run two end-to-end contenders alternately (first, second, first, ...) ``rounds`` times, so a
    background load affects both alike. Each is ``(name, fn)``, ``fn() -> dict`` with
    ``control_steps_per_s`` or ``error``. Returns ``{name: [result per round]}`` and the per-round
    ratios first / second (rounds where either failed left out)."""
    runs: dict = {first[0]: [], second[0]: []}
    ratios = []
    for _ in range(rounds):
        a, b = first[1](), second[1]()
        runs[first[0]].append(a)
        runs[second[0]].append(b)
        if "error" not in a and "error" not in b:
            ratios.append(a["control_steps_per_s"] / b["control_steps_per_s"])
    return runs, ratios


def main(run) -> None:
    """``python -m benchmarks.bench_X [--quick | --smoke]``: print ``run(quick, smoke)`` as JSON."""
    import argparse
    import json

    ap = argparse.ArgumentParser()
    size = ap.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true")
    size.add_argument("--smoke", action="store_true")
    a = ap.parse_args()
    print(json.dumps(run(a.quick or a.smoke, smoke=a.smoke), indent=1))


def worker_main(worker: Callable[[bool, bool], dict], run: Callable[..., dict]) -> None:
    """The command line of a benchmark measured in a worker subprocess: with ``--worker``, print
    ``worker(quick, smoke)`` as one JSON line (what ``bench_learning.run_worker`` reads back), else
    ``run(quick, smoke)`` indented; ``--quick`` and ``--smoke`` as given."""
    import json
    import sys

    quick, smoke = "--quick" in sys.argv, "--smoke" in sys.argv
    if "--worker" in sys.argv:
        print(json.dumps(worker(quick, smoke)))
    else:
        print(json.dumps(run(quick, smoke), indent=1))
