#!/bin/bash
# Stage 32 judge: the rule in configs/ship-tiny-cpu-stage32.yaml, which benchmarks/judge_guarded_stage.sh runs.
exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 32 --focal-over-averages
