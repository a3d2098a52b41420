#!/bin/bash
# Stage 35 judge: the rule in configs/ship-tiny-cpu-stage35.yaml, which benchmarks/judge_guarded_stage.sh runs.
CAMERA_EVERY=1 PROBE_STEPS="625 750 875 1000" exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 35 --focal-over-averages
