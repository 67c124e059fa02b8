#!/usr/bin/env bash
# The exploration x control-step study (nmrl/experiments/exploration_study.py, docs/exploration-study.md):
# the native PPO with white, nm-periods, ou and colored exploration at control steps 20, 5 and 10 ms
# (in that order), 4 seeds per cell, 16 PPO iterations per run (1.05*10^5 simulated seconds summed
# over 64 environments at every control step), after a screen at 5 ms that fixes one setting per
# correlated process. Niced; resumable on any machine: run the same script again. Where runs/ holds
# no copy of a cell, it starts from the published, committed compact states in $PUBLISHED.
# Publish the progress with: .venv/bin/python scripts/publish_exploration.py
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/exploration}
PUBLISHED=${PUBLISHED:-results/exploration/runs}
# Compiled programs are kept on disk: a cell's second leg (after its mid-training copy), its
# evaluations and a continued study load them instead of compiling again (about a minute each).
export JAX_COMPILATION_CACHE_DIR=${JAX_COMPILATION_CACHE_DIR:-$PWD/runs/xla-cache}
args=(--out "$OUT")
if [ -d "$PUBLISHED" ]; then args+=(--published "$PUBLISHED"); fi
# shellcheck source=scripts/lower_priority.sh
source scripts/lower_priority.sh
lower_priority
exec nice -n "${NICE:-19}" .venv/bin/nmrl explore-study "${args[@]}" "$@"
