#!/usr/bin/env bash
# The native PPO against its peer: nmrl's PPO (nmrl/learners/ppo.py) with white noise at the Brax
# baseline's settings (control step 20 ms, 64 environments, unroll 0.4 s, 32 minibatches x 512
# unrolls, 8 epochs, lr 3e-4, entropy 1e-3, policy 4x32, value 5x256), 3 seeds, 16 PPO iterations =
# 81,920 control steps per environment = 5.24*10^6 control steps summed over the environments (the
# Brax runs' step count), one chunk per iteration, as the points of one `nmrl sweep`, niced.
#
# Resumable, also on a fresh clone: run the same script again. It continues from the full
# checkpoints in $OUT when they exist; otherwise it seeds $OUT from the published, committed
# $PUBLISHED (sweep.json, every point's config, metrics and compact continuation state: parameters,
# Adam state and observation statistics; every environment starts a new trial).
# Publish the progress with: .venv/bin/python scripts/publish/publish_ppo_validation.py
# PHYSICS=c runs the same on MuJoCo C (the C physics' learning check, against the MJX runs):
#   OUT=runs/ppo_validation_c PUBLISHED=results/physics_c/ppo/validation PHYSICS=c scripts/run/ppo_validation.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
# shellcheck source=scripts/run/lower_priority.sh
source scripts/run/lower_priority.sh
lower_priority  # a background launch (setsid) yields the CPUs to interactive work
OUT=${OUT:-runs/ppo_validation}
PUBLISHED=${PUBLISHED:-results/ppo/validation}
STEPS=${STEPS:-81920}
PHYSICS=${PHYSICS:-mjx}
. scripts/run/seed_run.sh
seed_run "$OUT" "$PUBLISHED"
if [ -f "$OUT/sweep.json" ]; then
  exec nice -n "${NICE:-19}" .venv/bin/nmrl sweep --resume --out "$OUT" --steps "$STEPS" --checkpoint-every 1
fi
exec nice -n "${NICE:-19}" .venv/bin/nmrl sweep --learner ppo --exploration white --seeds 3 \
  --num-envs 64 --chunk-steps 5120 --steps "$STEPS" --checkpoint-every 1 --physics "$PHYSICS" --out "$OUT"
