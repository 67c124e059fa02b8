#!/usr/bin/env bash
# The paper's experiment (Sec. V-D, Fig. 3) at the paper's scale: l in {1,2,3,5,10,15,20,30} x 3
# seeds, the paper's step sizes (Table II / Sec. V-C), 10^5 trials per point, 32 environments per
# point (the layout chosen in benchmarks/bench_sweep.py: points split over the CPU cores, one point
# at a time per core). The paper's named points l = 1, 10, 30 (all seeds) run to 10^5 trials first.
#
# Resumable, also on a fresh clone: run the same script again. It continues from the full
# checkpoints in $OUT when they exist; otherwise it seeds $OUT from the published, committed
# $PUBLISHED (sweep.json, every point's config, metrics and compact continuation state) and
# continues from the compact states (statistically, not bitwise, equal: every environment starts
# a new trial). Publish the progress with: .venv/bin/python scripts/publish/publish_fig3_paper.py
#
# PRESET=fast uses the "fast" step sizes (nmrl/learners/ac_config.py) instead of the paper's.
# CPUS=0 (a taskset list) runs it on those cores only, with one XLA device per core: the way to
# share the machine with another long run (scripts/run/baseline_ppo.sh with CPUS=1), since the sweep's
# devices step in one program and one busy core holds them all back.
set -euo pipefail
cd "$(dirname "$0")/../.."
# shellcheck source=scripts/run/lower_priority.sh
source scripts/run/lower_priority.sh
lower_priority  # a background launch (setsid) yields the CPUs to interactive work
PRESET=${PRESET:-paper}
OUT=${OUT:-runs/fig3_$PRESET}
PUBLISHED=${PUBLISHED:-results/fig3_$PRESET}
TRIALS=${TRIALS:-100000}
NUM_ENVS=${NUM_ENVS:-32}
. scripts/run/seed_run.sh
seed_run "$OUT" "$PUBLISHED"
PIN=()
if [ -n "${CPUS:-}" ]; then PIN=(taskset -c "$CPUS"); fi
if [ -f "$OUT/sweep.json" ]; then
  exec nice -n "${NICE:-19}" ${PIN[@]+"${PIN[@]}"} .venv/bin/nmrl sweep --resume --l 1 --out "$OUT" --trials "$TRIALS" \
    --checkpoint-every 2
fi
exec nice -n "${NICE:-19}" ${PIN[@]+"${PIN[@]}"} .venv/bin/nmrl sweep --l 1 2 3 5 10 15 20 30 --seeds 3 --first 1 10 30 \
  --num-envs "$NUM_ENVS" --chunk-steps 1000 --preset "$PRESET" --trials "$TRIALS" --checkpoint-every 2 \
  --out "$OUT"
