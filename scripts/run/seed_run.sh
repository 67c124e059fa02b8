# Sourced by scripts/run/fig3_paper.sh and scripts/run/fast_preset.sh: seed_run OUT PUBLISHED copies a
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
