#!/usr/bin/env bash
# The third study, the thesis with the paper's actor-critic (docs/thesis-actor-critic.md,
# nmrl/experiments/thesis_ac.py), in the background, resumable on any machine.
#
#   scripts/run/thesis_ac.sh start    # start or resume (a fresh clone seeds from results/thesis_ac)
#   scripts/run/thesis_ac.sh status   # what runs, the log's last lines, each cell's progress and time left
#   scripts/run/thesis_ac.sh stop     # SIGTERM, wait for the sweep in flight to save, publish
#
# start runs `python -m nmrl.experiments.thesis_ac run` in its own session at the lowest CPU
# share (scripts/run/lower_priority.sh), logging to runs/thesis_ac.log. stop sends SIGTERM to that
# session (the sweep saves every active point after its chunk: up to 10 simulated seconds per
# environment, 17-36 s of wall time), then publishes the compact states and rows to results/thesis_ac (commit it).
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=${PY:-.venv/bin/python}
OUT=${OUT:-runs/thesis_ac}
PUB=${PUB:-results/thesis_ac}
PAT="nmrl.experiments.thesis_ac run --out $OUT"
STOP_TIMEOUT=${STOP_TIMEOUT:-1800}

case "${1:-}" in
  start)
    if pgrep -f "$PAT" > /dev/null; then echo "already running"; exit 0; fi
    mkdir -p runs
    setsid bash -c "source scripts/run/lower_priority.sh; lower_priority; exec nice -n \${NICE:-19} $PY -m $PAT \
      --published $PUB" >> runs/thesis_ac.log 2>&1 < /dev/null &
    echo "started (log: runs/thesis_ac.log)"
    ;;
  status)
    pgrep -af "$PAT|nmrl.cli sweep" || echo "not running"
    tail -n 5 runs/thesis_ac.log 2>/dev/null || true
    [ -d "$OUT" ] && "$PY" -m nmrl.experiments.thesis_ac progress --out "$OUT" || true
    ;;
  stop)
    pids=$(pgrep -f "$PAT" || true)
    for p in $pids; do kill -TERM -- "-$(ps -o sid= -p "$p" | tr -d ' ')" 2>/dev/null || kill -TERM "$p"; done
    for _ in $(seq "$STOP_TIMEOUT"); do
      pgrep -f "$PAT|nmrl.cli sweep .*--out $OUT" > /dev/null || break
      sleep 1
    done
    if pgrep -f "$PAT|nmrl.cli sweep .*--out $OUT" > /dev/null; then echo "still running after ${STOP_TIMEOUT}s"; exit 1; fi
    [ -d "$OUT" ] && "$PY" -m nmrl.experiments.thesis_ac publish --out "$OUT" --dest "$PUB"
    echo "stopped and published to $PUB"
    ;;
  *) echo "usage: $0 start|status|stop" >&2; exit 2 ;;
esac
