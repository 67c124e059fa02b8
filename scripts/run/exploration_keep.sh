#!/usr/bin/env bash
# Keeps the exploration study (scripts/exploration_study.sh) going and its progress published into
# results/exploration at an interval, so a commit of that folder at any moment holds the study's
# state of at most one interval ago. It commits nothing itself: what enters git is the caller's.
#
#   scripts/run/exploration_keep.sh start        # start or resume the study (also on a fresh clone)
#   scripts/run/exploration_keep.sh stop         # SIGTERM, wait for the saves, evaluate, publish
#   scripts/run/exploration_keep.sh watch [MIN]  # forever: every MIN minutes (default 40) stop,
#                                                # publish results/exploration, start again
#
# stop: the study saves every active point after the chunk in flight (full checkpoints in runs/, so
#   the restart continues bit-exactly); `--phases eval` then evaluates every finished run and writes
#   summary.json, and scripts/publish_exploration.py writes results/exploration. Exits 1 if the study
#   did not stop within STOP_TIMEOUT seconds (default 900), without publishing.
# watch: writes only results/exploration (through stop) and prints, after each publish, how many
#   runs results.csv holds. Run it in the background, e.g.
#     (setsid nohup scripts/run/exploration_keep.sh watch 45 >> runs/exploration_keep.log 2>&1 < /dev/null &)
#   and end it (pkill -f 'exploration_keep.sh watch') before a final `stop`.
set -euo pipefail
cd "$(dirname "$0")/../.."
PAT=${STUDY_PAT:-'nmrl explore-study --out runs/exploration'}
PY=${PY:-.venv/bin/python}
NMRL=${NMRL:-.venv/bin/nmrl}
export JAX_COMPILATION_CACHE_DIR=${JAX_COMPILATION_CACHE_DIR:-$PWD/runs/xla-cache}

start() {
  mkdir -p runs
  if pgrep -f "$PAT" > /dev/null; then echo "the study is running"; return 0; fi
  (setsid nohup scripts/exploration_study.sh >> runs/exploration.log 2>&1 < /dev/null &)
  echo "started the exploration study (runs/exploration.log)"
}

stop() {
  pkill -TERM -f "$PAT" || true
  local t=0
  while pgrep -f "$PAT" > /dev/null; do
    sleep 5; t=$((t + 5))
    if [ "$t" -ge "${STOP_TIMEOUT:-900}" ]; then echo "the study did not stop within ${STOP_TIMEOUT:-900} s" >&2; return 1; fi
  done
  if [ -f runs/exploration/study.json ]; then
    nice -n 19 "$NMRL" explore-study --out runs/exploration --phases eval --quiet
    nice -n 19 "$PY" scripts/publish_exploration.py
  fi
}

published() {
  local n
  n=$("$PY" -c 'import csv; print(sum(1 for _ in csv.DictReader(open("results/exploration/results.csv"))))' 2>/dev/null || echo "?")
  echo "$(date -u +%FT%TZ) published results/exploration ($n runs in results.csv)"
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  watch)
    min=${2:-40}
    if ! [[ "$min" =~ ^[0-9]+$ ]] || [ "$min" -lt 5 ]; then
      echo "watch: MIN=${min} is invalid: a whole number of minutes >= 5" >&2; exit 2
    fi
    # shellcheck source=scripts/lower_priority.sh
    source scripts/lower_priority.sh
    lower_priority  # its evaluations and publishing, as the study (scripts/lower_priority.sh)
    start
    while true; do
      sleep "${INTERVAL_S:-$((min * 60))}"
      echo "$(date -u +%FT%TZ) publishing"
      if stop; then published; fi
      start
    done ;;
  *) echo "usage: scripts/run/exploration_keep.sh start|stop|watch [MIN]" >&2; exit 2 ;;
esac
