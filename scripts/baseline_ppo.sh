#!/usr/bin/env bash
# The peer on the same robot (issue 18): Brax PPO on the paper's Half-Cheetah, 2.5*10^7 control
# steps per seed (the samples of 10^5 trials), seeds 0 1 2 one after another, niced (the machine
# is shared with the paper-scale Fig. 3 run). Needs the optional extra: pip install -e '.[brax]'.
#
# Resumable: run the same script again; a seed with a run directory continues from its newest
# checkpoint (fresh Adam state and environments: statistically, not bitwise, the same run; see
# nmrl/experiments/baseline_ppo.py), a finished seed is skipped. SIGTERM stops after the PPO
# iteration in flight is saved (exit 143). Publish with: .venv/bin/python scripts/publish_baseline_ppo.py
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/baseline_ppo}
SEEDS=${SEEDS:-0 1 2}
mkdir -p "$OUT"
for s in $SEEDS; do
  d="$OUT/ppo_s$s"
  if [ -f "$d/config.json" ]; then
    nice -n "${NICE:-19}" .venv/bin/nmrl baseline ppo --resume --out "$d"
  else
    nice -n "${NICE:-19}" .venv/bin/nmrl baseline ppo --seed "$s" --out "$d"
  fi
done
