#!/usr/bin/env bash
# The second exploration study (docs/exploration-study-2.md, nmrl/experiments/exploration2.py) in
# the background, resumable on any machine.
# start | status | stop, as scripts/run/study.sh exploration2 describes.
exec "$(dirname "$0")/study.sh" exploration2 "$@"
