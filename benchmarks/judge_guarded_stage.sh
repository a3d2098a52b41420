#!/bin/bash
# The camera-guarded ship rule of stages 29 and later, as a script (each stage's config states it before it runs):
#   bash benchmarks/judge_guarded_stage.sh N
# Start: /work/judgeN/start (a copy of the shipped weights made before training). Run from /work/main after
# `d4rt train --config configs/ship-tiny-cpu-stageN.yaml --out /work/runs/ship-tiny-stageN` has been started.
# 1. The kept raw checkpoints of steps 2,500-4,000 go through the held-out camera probe; the lowest is step S.
# 2. The start and (1 - w) x start + w x S for w = 0.25, 0.5, 0.75 go through the same probe; the candidate is the
#    largest w not worse than the start (none: stop).
# 3. Focal gate: synthetic median below the shipped figure, real TUM within 20%. 4. Passed: `d4rt eval`.
# With --focal-over-averages (stage 32 on; stated in its config before it ran) step 3 goes through every average that
# kept the start's camera, largest w first, and the candidate is the first that passes the focal gate.
set -e
N=${1:?usage: judge_guarded_stage.sh STAGE_NUMBER [--focal-over-averages]}
EACH=${2:-}
cd /work/main
RUN=/work/runs/ship-tiny-stage$N
export J=/work/judge$N
while pgrep -f "ship-tiny-cpu-stage$N.yaml" >/dev/null; do sleep 20; done
echo "training ended $(date -u)" >> $J/judge.log
CK=""
for s in 2500 3000 3500 4000; do CK="$CK $RUN/checkpoints/step-0000$s"; done
python tools/camera_probe.py $CK --frames 24 --time-stride 1 --out $J/camera-probe-24-frames.json >> $J/judge.log 2>&1
S=$(python -c "
import json, os
d=json.load(open(os.environ['J'] + '/camera-probe-24-frames.json'))
print(min(d['models'], key=lambda k: d['models'][k]['trajectory_ate']['adjacent']['mean']))")
echo "S=$S $(date -u)" >> $J/judge.log
for w in 0.25 0.5 0.75; do
  python tools/average_weights.py $J/start $S --weights $(python -c "print(1-$w)") $w --out $J/avg-$w >> $J/judge.log 2>&1
done
python tools/camera_probe.py $J/start $J/avg-0.25 $J/avg-0.5 $J/avg-0.75 --frames 24 --time-stride 1 \
    --out $J/camera-probe-candidates-24-frames.json >> $J/judge.log 2>&1
W=$(python -c "
import json, os
J=os.environ['J']
d=json.load(open(J + '/camera-probe-candidates-24-frames.json'))['models']
ate={k: v['trajectory_ate']['adjacent']['mean'] for k, v in d.items()}
ok=[w for w in ('0.75', '0.5', '0.25') if ate[J + '/avg-' + w] <= ate[J + '/start']]
print(' '.join(ok) if ok else 'none')")
echo "w kept the camera: $W $(date -u)" >> $J/judge.log
[ "$W" = none ] && { echo "stopped: no average keeps the start's camera" >> $J/judge.log; exit 0; }
[ "$EACH" = --focal-over-averages ] || W=${W%% *}  # the rule of stages 29-31: the largest such w alone
for w in $W; do
  rm -rf $J/candidate && cp -r $J/avg-$w $J/candidate
  python tools/measure_focal.py --checkpoint $J/candidate --out $J/focal-avg-$w.json >> $J/judge.log 2>&1
  cp $J/focal-avg-$w.json $J/focal.json
  python - <<'P' >> $J/judge.log
import json, os
J = os.environ["J"]
n = json.load(open(J + "/focal.json")); o = json.load(open("/work/main/docs/model-card/focal.json"))
a = n["synthetic-dynamic-v1"]["median_focal_error"]; b = o["synthetic-dynamic-v1"]["median_focal_error"]
t = n["tum-fr3-long-office-household"]["relative_error"]
ok = a < b and abs(t) <= 0.20
print(f"focal gate: synthetic {a:.4f} vs shipped {b:.4f}, TUM {t:+.4f} -> {'PASS' if ok else 'FAIL'}")
open(J + "/gate", "w").write("PASS" if ok else "FAIL")
P
  echo "w=$w $(date -u)" >> $J/judge.log
  [ "$(cat $J/gate)" = PASS ] && break
done
if [ "$(cat $J/gate)" = PASS ]; then
  d4rt eval --benchmark synthetic-dynamic-v1 --checkpoint $J/candidate --baseline oracle --baseline constant-depth \
     --out $J/eval.json --no-progress > $J/eval.md 2>> $J/judge.log
  echo "eval done $(date -u)" >> $J/judge.log
fi
