#!/bin/bash
# Stage 38 judge: the rule in configs/ship-tiny-cpu-stage38.yaml, which benchmarks/judge_guarded_stage.sh runs.
CAMERA_EVERY=1 PROBE_STEPS="1875 2250 2625 3000" PROBE_EMA=3000 exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 38 --focal-over-averages
