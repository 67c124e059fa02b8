#!/usr/bin/env bash
# The peer on the same robot: Brax PPO on the paper's Half-Cheetah, 2.5*10^7 control
# steps per seed (the samples of 10^5 trials), seeds 0 1 2 one after another, niced (the machine
# is shared with the paper-scale Fig. 3 run). Needs the optional extra: pip install -e '.[brax]'.
#
# Resumable, also on a fresh clone: run the same script again. A seed with a run directory in $OUT
# continues from its newest checkpoint; a seed without one that was published in $PUBLISHED
# (scripts/publish/publish_baseline_ppo.py: config, metrics, resumes and, while unfinished, compact.npz,
# the newest parameters) is copied there first and continues from its compact.npz, which holds the
# same arrays as the newest checkpoint. A continuation has a fresh Adam state and environments:
# statistically, not bitwise, the uninterrupted run (see nmrl/experiments/baseline_ppo.py). A
# finished seed (published without parameters) is skipped: its --resume does nothing. SIGTERM
# stops after the PPO iteration in flight is saved (exit 143).
# Publish with: .venv/bin/python scripts/publish/publish_baseline_ppo.py
# CPUS=1 (a taskset list) runs it on those cores only (one XLA device per core): beside the
# Fig. 3 sweep pinned to the other core (CPUS=0 scripts/run/fig3_paper.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."
. scripts/run/seed_run.sh
# shellcheck source=scripts/run/lower_priority.sh
source scripts/run/lower_priority.sh
lower_priority  # a background launch (setsid) yields the CPUs to interactive work
OUT=${OUT:-runs/baseline_ppo}
PUBLISHED=${PUBLISHED:-results/baseline_ppo}
SEEDS=${SEEDS:-0 1 2}
mkdir -p "$OUT"
PIN=()
if [ -n "${CPUS:-}" ]; then PIN=(taskset -c "$CPUS"); fi
for s in $SEEDS; do
  d="$OUT/ppo_s$s"
  p="$PUBLISHED/ppo_s$s"
  seed_baseline_run "$d" "$p"
  if [ -f "$d/config.json" ]; then
    nice -n "${NICE:-19}" ${PIN[@]+"${PIN[@]}"} .venv/bin/nmrl baseline ppo --resume --out "$d"
  else
    nice -n "${NICE:-19}" ${PIN[@]+"${PIN[@]}"} .venv/bin/nmrl baseline ppo --seed "$s" --out "$d"
  fi
done
