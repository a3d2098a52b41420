#!/bin/bash
# Stage 37 judge: the rule in configs/ship-tiny-cpu-stage37.yaml, which benchmarks/judge_guarded_stage.sh runs.
CAMERA_EVERY=1 PROBE_STEPS="625 750 875 1000" exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 37 --focal-over-averages
