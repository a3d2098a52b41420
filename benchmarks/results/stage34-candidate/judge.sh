#!/bin/bash
# Stage 34 judge: the rule in configs/ship-tiny-cpu-stage34.yaml, which benchmarks/judge_guarded_stage.sh runs.
CAMERA_EVERY=1 exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 34 --focal-over-averages
