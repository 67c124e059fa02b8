#!/usr/bin/env bash
# The third study, the thesis with the paper's actor-critic (docs/thesis-actor-critic.md,
# nmrl/experiments/thesis_ac.py), in the background, resumable on any machine.
# start | status | stop, as scripts/run/study.sh thesis_ac describes.
exec "$(dirname "$0")/study.sh" thesis_ac "$@"
