#!/bin/bash
# Stage 31 judge: the rule in configs/ship-tiny-cpu-stage31.yaml, which benchmarks/judge_guarded_stage.sh runs.
exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 31
