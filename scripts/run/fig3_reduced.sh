#!/usr/bin/env bash
# Fig. 3 at a reduced scale a 2-core machine runs in about an hour: the paper's sweep
# (l in {1,2,3,5,10,15,20,30} x 3 seeds, 64 environments per point) with the "fast" step sizes,
# stopped at 2500 trials per point. Wall time measured: docs/fig3.md (reduced scale).
# Resumable: run it again to continue; raise TRIALS to go further.
set -euo pipefail
cd "$(dirname "$0")/../.."
PRESET=fast TRIALS=${TRIALS:-2500} OUT=${OUT:-runs/fig3_reduced} exec scripts/run/fig3_paper.sh
