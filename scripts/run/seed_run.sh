# Sourced by the launchers in scripts/run/ (fig3_paper.sh, fast_preset.sh, baseline_ppo.sh, task_validation.sh): seed_run OUT PUBLISHED copies a
# published sweep's continuation state (sweep.json, every point's config.json, metrics.jsonl and
# compact.npz; a point that never ran has only its config) into OUT when OUT holds no sweep yet, so
# that `nmrl sweep --resume` continues it from the compact states on a fresh clone.
seed_run() {
  local out=$1 published=$2 p d f
  if [ ! -f "$out/sweep.json" ] && [ -f "$published/sweep.json" ] && [ -d "$published/points" ]; then
    echo "seeding $out from the published $published (compact continuation states)" >&2
    mkdir -p "$out"
    cp "$published/sweep.json" "$out/"
    for p in "$published"/points/*/; do
      d="$out/points/$(basename "$p")"; mkdir -p "$d"
      for f in config.json metrics.jsonl compact.npz; do
        if [ -f "$p/$f" ]; then cp "$p/$f" "$d/"; fi
      done
    done
  fi
}

# seed_baseline_run OUT PUBLISHED: the same for one Brax PPO baseline run (config.json, metrics.jsonl,
# resumes.jsonl and its compact state), so that `nmrl baseline ppo --resume` continues it.
seed_baseline_run() {
  local out=$1 published=$2 f
  if [ ! -f "$out/config.json" ] && [ -f "$published/config.json" ]; then
    echo "seeding $out from the published $published (its compact continuation state, if unfinished)" >&2
    mkdir -p "$out"
    for f in config.json metrics.jsonl resumes.jsonl compact.npz; do
      if [ -f "$published/$f" ]; then cp "$published/$f" "$out/"; fi
    done
  fi
}
