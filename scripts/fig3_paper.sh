#!/usr/bin/env bash
# The paper's experiment (Sec. V-D, Fig. 3): l in {1,2,3,5,10,15,20,30} x 3 seeds, paper's step
# sizes, 64 environments per point, aiming at 10^5 trials per point. Resumable: run the same
# script again and it continues from the last checkpoint shared by all points.
# Measured on the 2-core reference machine: see README ("Reproducing Fig. 3") for the wall time.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/fig3_paper}
if [ -f "$OUT/sweep.json" ]; then
  exec .venv/bin/nmrl sweep --resume --l 1 --out "$OUT" --trials 100000 --checkpoint-every 4 --quiet
fi
exec .venv/bin/nmrl sweep --l 1 2 3 5 10 15 20 30 --seeds 3 --num-envs 64 --chunk-steps 250 \
  --trials 100000 --checkpoint-every 4 --out "$OUT" --quiet
