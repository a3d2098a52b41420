#!/bin/bash
# Stage 29 judge: the rule in configs/ship-tiny-cpu-stage29.yaml, which benchmarks/judge_guarded_stage.sh runs.
exec bash "$(dirname "$0")/../../judge_guarded_stage.sh" 29
