#!/bin/bash
# Stage 33 judge: stages 31 and 32's step S averaged into the shipped weights (README.md states the rule).
# Needs /work/judge33/start (the shipped weights) and both runs' checkpoints from their stages' commands.
exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 33 --focal-over-averages --soup-of \
  /work/runs/ship-tiny-stage31/checkpoints/step-00002500 /work/runs/ship-tiny-stage32/checkpoints/step-00002500
