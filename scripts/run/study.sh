#!/usr/bin/env bash
# A pre-registered study (a module of nmrl/experiments with the study kit's `run`, `progress` and
# `publish` commands, nmrl/experiments/kit_cli.py) in the background, resumable on any machine.
#
#   scripts/run/study.sh NAME start    # start or resume (a fresh clone seeds from the published states)
#   scripts/run/study.sh NAME status   # what runs, the log's last lines, each cell's progress and time left
#   scripts/run/study.sh NAME stop     # SIGTERM, wait for the sweep in flight to save, publish
#
# NAME is the study's module, nmrl.experiments.NAME (exploration2, thesis_ac). start runs
# `python -m nmrl.experiments.NAME run --out runs/NAME --published PUB` in its own session at the
# lowest CPU share (scripts/run/lower_priority.sh), logging to runs/NAME.log. stop sends SIGTERM to
# that session (the sweep saves every active point after its chunk), waits up to STOP_TIMEOUT
# seconds, then publishes the compact states and rows to PUB (commit it). The sweeps get a grace of
# STOP_TIMEOUT seconds (NMRL_GRACE_S, docs/runs.md), so that stop keeps the chunk in flight. PUB is the study's
# published directory: results/exploration2/runs for exploration2, results/exploration2/amendment
# for exploration2_amendment, results/NAME otherwise.
set -euo pipefail
cd "$(dirname "$0")/../.."
NAME=${1:-}
case "$NAME" in
  ""|*[!a-z0-9_]*) echo "usage: $0 NAME start|status|stop (NAME: a study module of nmrl/experiments, e.g. thesis_ac)" >&2; exit 2 ;;
esac
PY=${PY:-.venv/bin/python}
MOD="nmrl.experiments.$NAME"
OUT=${OUT:-runs/$NAME}
case "$NAME" in
  exploration2) PUB=${PUB:-results/exploration2/runs} ;;
  exploration2_amendment) PUB=${PUB:-results/exploration2/amendment} ;;
  *) PUB=${PUB:-results/$NAME} ;;
esac
LOG=${LOG:-runs/$NAME.log}
PAT="$MOD run --out $OUT"
STOP_TIMEOUT=${STOP_TIMEOUT:-1800}

case "${2:-}" in
  start)
    if pgrep -f "$PAT" > /dev/null; then echo "already running"; exit 0; fi
    mkdir -p "$(dirname "$LOG")"
    NMRL_GRACE_S=${NMRL_GRACE_S:-$STOP_TIMEOUT} setsid bash -c "source scripts/run/lower_priority.sh; lower_priority; exec nice -n \${NICE:-19} $PY -m $PAT \
      --published $PUB" >> "$LOG" 2>&1 < /dev/null &
    echo "started (log: $LOG)"
    ;;
  status)
    pgrep -af "$PAT|nmrl.cli sweep .*--out $OUT" || echo "not running"
    tail -n 5 "$LOG" 2>/dev/null || true
    [ -d "$OUT" ] && "$PY" -m "$MOD" progress --out "$OUT" || true
    ;;
  stop)
    pids=$(pgrep -f "$PAT" || true)
    for p in $pids; do kill -TERM -- "-$(ps -o sid= -p "$p" | tr -d ' ')" 2>/dev/null || kill -TERM "$p"; done
    for _ in $(seq "$STOP_TIMEOUT"); do
      pgrep -f "$PAT|nmrl.cli sweep .*--out $OUT" > /dev/null || break
      sleep 1
    done
    if pgrep -f "$PAT|nmrl.cli sweep .*--out $OUT" > /dev/null; then echo "still running after ${STOP_TIMEOUT}s"; exit 1; fi
    [ -d "$OUT" ] && "$PY" -m "$MOD" publish --out "$OUT" --dest "$PUB"
    echo "stopped and published to $PUB"
    ;;
  *) echo "usage: $0 NAME start|status|stop" >&2; exit 2 ;;
esac
