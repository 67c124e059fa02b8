#!/usr/bin/env bash
# The project's two long runs, resumable on any machine: the paper-scale Fig. 3 sweep
# (scripts/run/fig3_paper.sh) and the Brax PPO baseline (scripts/run/baseline_ppo.sh).
#
#   scripts/run/background.sh start    # start or resume both (also on a fresh clone)
#   scripts/run/background.sh status   # their last lines, the sweep's last chunk times, what runs
#   scripts/run/background.sh stop     # before the machine goes away: SIGTERM, wait for the saves, publish
#
# start: with 2 or more cores and Brax installed (pip install -e '.[brax]'), the sweep runs on
#   core 0 and PPO on core 1 (CPUS=..., one XLA device each): the sweep's devices step in one
#   program, so a second run sharing its cores would hold it back far more than its share. With
#   one core, or without Brax, the sweep alone, on every core. Each run resumes where it stopped
#   (full checkpoints in runs/, else the compact states published under results/). A run already
#   going is left alone. Logs: runs/fig3_paper.log, runs/baseline_ppo.log. Once PPO has finished
#   every seed (2.5*10^7 control steps each), the sweep gets every core: at start when PPO is
#   already done, and while they run by a hand-off that follows the PPO script when it ends
#   normally (SIGTERM the pinned sweep, wait for its save, resume it on every core).
# stop: SIGTERM to both; the sweep saves every active point after its chunk, PPO after the
#   iteration in flight (up to ~5 min on one core); then scripts/publish/publish_fig3_paper.py and
#   scripts/publish/publish_baseline_ppo.py write results/ (commit it). Exits 1 if a run did not stop
#   within STOP_TIMEOUT seconds (default 900), without publishing that run.
set -euo pipefail
cd "$(dirname "$0")/../.."
SWEEP_PAT=${SWEEP_PAT:-'nmrl sweep --resume --l 1 --out runs/fig3_paper'}
PPO_PAT=${PPO_PAT:-'nmrl baseline ppo'}
PY=${PY:-.venv/bin/python}

running() { pgrep -f "$1" > /dev/null; }

has_brax() { "$PY" -c 'import brax' > /dev/null 2>&1; }

ppo_done() {  # 0 when every PPO seed's newest metrics (runs/, else the published copy) reached its budget
  "$PY" - "${SEEDS:-0 1 2}" <<'PYEOF'
import json, pathlib, sys
for s in sys.argv[1].split():
    for root in ("runs/baseline_ppo", "results/baseline_ppo"):
        d = pathlib.Path(root) / f"ppo_s{s}"
        if (d / "config.json").is_file() and (d / "metrics.jsonl").is_file():
            break
    else:
        sys.exit(1)
    budget = json.loads((d / "config.json").read_text())["num_timesteps"]
    lines = (d / "metrics.jsonl").read_text().splitlines()
    if not lines or json.loads(lines[-1])["step"] < budget:
        sys.exit(1)
PYEOF
}

start_sweep() {  # [cpus]: the sweep, on those cores or (empty) on every core
  if [ -n "${1:-}" ]; then
    (CPUS=$1 setsid scripts/run/fig3_paper.sh >> runs/fig3_paper.log 2>&1 &)
    echo "started the Fig. 3 sweep on core $1 (runs/fig3_paper.log)"
  else
    (env -u CPUS setsid scripts/run/fig3_paper.sh >> runs/fig3_paper.log 2>&1 &)
    echo "started the Fig. 3 sweep on every core (runs/fig3_paper.log)"
  fi
}

start() {
  mkdir -p runs
  rm -f runs/background.stopping
  local cores; cores=$(nproc)
  local both=0
  if [ "$cores" -ge 2 ] && has_brax && ! ppo_done; then both=1; fi
  if running "$SWEEP_PAT"; then
    echo "the Fig. 3 sweep is already running"
  elif [ "$both" = 1 ]; then
    start_sweep 0
  else
    start_sweep ""
  fi
  if [ "$both" = 1 ]; then
    if running "$PPO_PAT"; then
      echo "the PPO baseline is already running"
    else
      (CPUS=1 setsid bash -c 'scripts/run/baseline_ppo.sh && scripts/run/background.sh handoff' \
        >> runs/baseline_ppo.log 2>&1 &)
      echo "started the PPO baseline on core 1 (runs/baseline_ppo.log)"
    fi
  elif ! has_brax; then
    echo "the PPO baseline needs the optional extra: .venv/bin/pip install -e '.[brax]'" >&2
  elif [ "$cores" -lt 2 ]; then
    echo "one core: the PPO baseline is not started beside the sweep" >&2
  else
    echo "the PPO baseline has finished every seed: nothing to start (publish with scripts/run/background.sh stop)"
  fi
}

handoff() {  # after the PPO script ended normally: the sweep moves from core 0 to every core
  if [ -e runs/background.stopping ] || ! ppo_done; then return 0; fi
  echo "PPO finished every seed: moving the Fig. 3 sweep to every core"
  if running "$SWEEP_PAT"; then
    pkill -TERM -f "$SWEEP_PAT" || true
    wait_gone "$SWEEP_PAT" || { echo "the sweep did not stop; left as it was" >&2; return 1; }
  fi
  if [ ! -e runs/background.stopping ]; then start_sweep ""; fi
}

status() {
  for f in runs/fig3_paper.log runs/baseline_ppo.log; do
    if [ -f "$f" ]; then echo "== $f"; tail -n 3 "$f"; fi
  done
  if [ -f runs/fig3_paper.log ]; then  # the sweep's newest chunk times (its log has the running total)
    awk '/^compiled the sweep chunk/ {n = 0; prev = 0}
         /^sweep: [0-9]+ points, [0-9,]+ s$/ {t = $4; gsub(",", "", t); d[++n] = t - prev; prev = t}
         END {if (n) {s = "sweep: its last chunks took"; for (i = (n > 5 ? n - 4 : 1); i <= n; i++) s = s " " d[i];
                      print s " s"}}' \
      runs/fig3_paper.log
  fi
  running "$SWEEP_PAT" && echo "sweep: running" || echo "sweep: not running"
  running "$PPO_PAT" && echo "ppo: running" || echo "ppo: not running"
}

wait_gone() {  # pattern -> 0 once no process matches, 1 after STOP_TIMEOUT seconds
  local t=0
  while running "$1"; do
    if [ "$t" -ge "${STOP_TIMEOUT:-900}" ]; then return 1; fi
    sleep 5; t=$((t + 5))
  done
}

stop() {
  local rc=0
  mkdir -p runs && touch runs/background.stopping
  pkill -TERM -f "$SWEEP_PAT" || true
  pkill -TERM -f "$PPO_PAT" || true
  if wait_gone "$SWEEP_PAT"; then
    if [ -f runs/fig3_paper/sweep.json ]; then "$PY" scripts/publish/publish_fig3_paper.py; fi
  else
    echo "the Fig. 3 sweep did not stop within ${STOP_TIMEOUT:-900} s; not published" >&2; rc=1
  fi
  if wait_gone "$PPO_PAT"; then
    if [ -d runs/baseline_ppo ] && has_brax; then "$PY" scripts/publish/publish_baseline_ppo.py; fi
  else
    echo "the PPO baseline did not stop within ${STOP_TIMEOUT:-900} s; not published" >&2; rc=1
  fi
  return "$rc"
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  status) status ;;
  handoff) handoff ;;
  *) echo "usage: scripts/run/background.sh start|status|stop (got '${1:-}')" >&2; exit 2 ;;
esac
