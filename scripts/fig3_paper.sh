#!/usr/bin/env bash
# The paper's experiment (Sec. V-D, Fig. 3) at the paper's scale: l in {1,2,3,5,10,15,20,30} x 3
# seeds, the paper's step sizes, 64 environments per point, 10^5 trials per point.
# Resumable: run the same script again and it continues from the last checkpoint all points share.
# PRESET=fast uses the "fast" step sizes (nmrl/learner.py) instead of the paper's.
set -euo pipefail
cd "$(dirname "$0")/.."
PRESET=${PRESET:-paper}
OUT=${OUT:-runs/fig3_$PRESET}
TRIALS=${TRIALS:-100000}
if [ -f "$OUT/sweep.json" ]; then
  exec .venv/bin/nmrl sweep --resume --l 1 --out "$OUT" --trials "$TRIALS" --checkpoint-every 4 --quiet
fi
exec .venv/bin/nmrl sweep --l 1 2 3 5 10 15 20 30 --seeds 3 --num-envs 64 --chunk-steps 250 \
  --preset "$PRESET" --trials "$TRIALS" --checkpoint-every 4 --out "$OUT" --quiet
