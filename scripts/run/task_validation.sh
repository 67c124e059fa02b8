#!/usr/bin/env bash
# PPO on Gymnasium's HalfCheetah-v5: nmrl's native PPO (white noise) against Brax's PPO through the
# Brax adapter (nmrl/adapters/brax_task.py) with the same settings, 3 seeds each, MuJoCo C physics,
# the task's own 0.05 s control step, 64 environments, unroll 8 steps (0.4 s), 32 minibatches x 512
# unrolls (131,072 control steps per iteration), 8 epochs, lr 3e-4, entropy 1e-3, clip 0.3,
# gamma 0.99, GAE lambda 0.95, observation and advantage normalisation, policy and value networks
# 2 x 64; 39 iterations = 5,111,808 control steps per seed. The native seeds run as the points of
# one `nmrl sweep`, the Brax seeds as three `nmrl baseline ppo` processes, all at once, niced.
# Needs Brax (pip install -e '.[brax]').
#
# Resumable, also on a fresh clone: run the same script again. Every run continues from its newest
# checkpoint in $OUT; a run with none there is first seeded from its published continuation state in
# $PUBLISHED (config, metrics and compact.npz: parameters, and for the native PPO its Adam state
# and observation statistics; every environment starts a new episode).
# Publish the progress with: .venv/bin/python scripts/publish/publish_standard_tasks.py
set -euo pipefail
cd "$(dirname "$0")/../.."
# Every process runs at nice $NICE (default 10) in the caller's session: the session's own CPU share
# (scripts/run/lower_priority.sh) is left as it is, so a setsid launch takes a session's share.
NICE=${NICE:-10}
OUT=${OUT:-runs/standard_tasks}
PUBLISHED=${PUBLISHED:-results/standard_tasks}
PY=${PY:-.venv/bin/python}
ITERATIONS=${ITERATIONS:-39}
SEEDS=(0 1 2)
# gamma = exp(-0.05 / horizon): 0.99 and 0.95 at the task's 0.05 s step
HORIZONS=(--discount-horizon-s 4.9749581236711045 --gae-horizon-s 0.9747862873111837)
. scripts/run/seed_run.sh
seed_run "$OUT/native" "$PUBLISHED/native"
mkdir -p "$OUT/brax"
pids=()
if [ -f "$OUT/native/sweep.json" ]; then
  nice -n "$NICE" "$PY" -m nmrl.cli sweep --resume --out "$OUT/native" --steps $((ITERATIONS * 2048)) \
    --checkpoint-every 1 > "$OUT/native.log" 2>&1 &
else
  nice -n "$NICE" "$PY" -m nmrl.cli sweep --learner ppo --env halfcheetah-v5 --physics c --exploration white \
    --seeds 3 --num-envs 64 --chunk-steps 2048 --steps $((ITERATIONS * 2048)) --checkpoint-every 1 \
    --policy-layers 2 --policy-width 64 --value-layers 2 --value-width 64 "${HORIZONS[@]}" \
    --out "$OUT/native" > "$OUT/native.log" 2>&1 &
fi
pids+=($!)
for s in "${SEEDS[@]}"; do
  d="$OUT/brax/ppo_s$s"
  p="$PUBLISHED/brax/ppo_s$s"
  seed_baseline_run "$d" "$p"
  if [ -f "$d/config.json" ]; then
    nice -n "$NICE" "$PY" -m nmrl.cli baseline ppo --resume --out "$d" --num-timesteps $((ITERATIONS * 131072)) \
      --devices 1 > "$OUT/brax_s$s.log" 2>&1 &
  else
    nice -n "$NICE" "$PY" -m nmrl.cli baseline ppo --env halfcheetah-v5 --physics c --devices 1 --seed "$s" \
      --num-envs 64 --unroll-length 8 --batch-size 512 --num-minibatches 32 --num-updates-per-batch 8 \
      --discounting 0.99 --learning-rate 3e-4 --entropy-cost 1e-3 --policy-hidden 64 64 --value-hidden 64 64 \
      --num-timesteps $((ITERATIONS * 131072)) --out "$d" > "$OUT/brax_s$s.log" 2>&1 &
  fi
  pids+=($!)
done
trap 'kill -TERM "${pids[@]}" 2>/dev/null; wait' TERM INT
wait
