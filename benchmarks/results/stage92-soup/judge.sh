#!/bin/bash
# Stage 92's judge, as README.md states it (run from /work/main; resumable: a stopped judge skips what it wrote).
set -e
mkdir -p /work/judge92/probe-cache
[ -d /work/judge92/start ] || cp -r src/d4rt/assets/d4rt-tiny /work/judge92/start
cmp -s /work/judge92/start/model.safetensors /work/judge90/start/model.safetensors  # the shipped weights, both
[ -f /work/judge92/probe-cache/_work_judge92_start.json ] || python -c "import json; d = json.load(open('/work/judge90/probe-cache/_work_judge90_start.json')); d['models'] = {'/work/judge92/start': d['models']['/work/judge90/start']}; json.dump(d, open('/work/judge92/probe-cache/_work_judge92_start.json', 'w'), indent=1)"
[ -f /work/judge92/focal-held-out-start.json ] || cp /work/judge90/focal-held-out-start.json /work/judge92/
PAIRING=best S_BY=focal FOCAL_GATE=noninferior CAMERA_TOLERANCE=1.25 AVERAGE_WEIGHTS="0.25 0.5 1" CAMERA_EVERY=1 \
  bash benchmarks/judge_guarded_stage.sh 92 --focal-over-averages --soup-of /work/runs/ship-tiny-stage88 \
  /work/runs/ship-tiny-stage89 /work/runs/ship-tiny-stage90
