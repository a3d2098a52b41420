#!/bin/bash
# Stage 30 judge: the rule in configs/ship-tiny-cpu-stage30.yaml, which benchmarks/judge_guarded_stage.sh runs.
exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 30
