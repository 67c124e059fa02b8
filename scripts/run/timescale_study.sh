#!/usr/bin/env bash
# Does learning survive a finer time discretization? (nmrl/experiments/study.py)
# delta in {0.02, 0.01, 0.005} s x {stationary, nm-periods of 0.1, 0.2, 0.4 s}: a 3x3 step-size grid
# per arm (1 seed, 40 simulated s), then 3 seeds per arm at the chosen step sizes (150 simulated s),
# then the per-period gradient variance of fixed policies, then the figures.
# Resumable: run the same command again and every phase continues where it stopped.
# Extra arguments go to `python -m nmrl.experiments.study` (they must be the same on every call).
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-runs/timescale}
exec .venv/bin/python -m nmrl.experiments.study --out "$OUT" "$@"
