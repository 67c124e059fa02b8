#!/usr/bin/env bash
# The confirmation sweep of a fast preset: the reduced Fig. 3 layout of
# results/fig3_fast/ -- l in {1,2,3,5,10,15,20,30} x 3 seeds, 64 environments per point, 250-step
# chunks -- to 5,000 trials per point, niced. PRESET picks the preset (default: fast_clip).
#
# Resumable: run it again; it continues from the checkpoints in $OUT (runs/ is not in git: on a
# fresh clone it starts over, ~1 h of a quiet 2-core machine). Publish with:
#   .venv/bin/python scripts/publish/publish_fast_preset.py --run $PRESET=$OUT
set -euo pipefail
cd "$(dirname "$0")/../.."
# shellcheck source=scripts/run/lower_priority.sh
source scripts/run/lower_priority.sh
lower_priority  # a background launch (setsid) yields the CPUs to interactive work
PRESET=${PRESET:-fast_clip}
OUT=${OUT:-runs/fast_preset/$PRESET}
TRIALS=${TRIALS:-5000}
if [ -f "$OUT/sweep.json" ]; then
  exec nice -n "${NICE:-19}" .venv/bin/nmrl sweep --resume --l 1 --out "$OUT" --trials "$TRIALS" \
    --checkpoint-every 4 --quiet
fi
exec nice -n "${NICE:-19}" .venv/bin/nmrl sweep --l 1 2 3 5 10 15 20 30 --seeds 3 --num-envs 64 \
  --chunk-steps 250 --preset "$PRESET" --trials "$TRIALS" --checkpoint-every 4 --out "$OUT" --quiet
