#!/bin/bash
# Stage 39 judge: the rule in configs/ship-tiny-cpu-stage39.yaml, which benchmarks/judge_guarded_stage.sh runs.
CAMERA_EVERY=1 PROBE_STEPS="5625 6750 7875 9000" PROBE_EMA=9000 exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 39 --focal-over-averages
