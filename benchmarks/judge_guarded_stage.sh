#!/bin/bash
# The camera-guarded ship rule of stages 29 and later, as a script (each stage's config states it before it runs):
#   bash benchmarks/judge_guarded_stage.sh N
# Start: /work/judgeN/start (a copy of the shipped weights made before training). Run from /work/main beside
# `d4rt train --config configs/ship-tiny-cpu-stageN.yaml --out /work/runs/ship-tiny-stageN` (started before or after).
# 1. The kept raw checkpoints of steps 2,500-4,000 (PROBE_STEPS) go through the held-out camera probe; the lowest is step S.
# 2. The start and (1 - w) x start + w x S for w = 0.25, 0.5, 0.75 go through the same probe; the candidate is the
#    largest w not worse than the start (times CAMERA_TOLERANCE, below; none: stop).
# 3. Focal gate: synthetic median below the shipped figure, real TUM within 20%. 4. Passed: `d4rt eval`.
# With --focal-over-averages (stage 32 on; stated in its config before its judge measured anything) the candidate is
# instead the largest w that kept the start's camera and whose synthetic focal error on held-out clips
# (tools/measure_focal.py --held-out: the benchmark's clip definitions from seeds it never uses) is below the start's;
# the benchmark's focal gate (step 3) then runs once, on that candidate alone, so no choice looks at the benchmark.
# With --soup-of CK1 CK2 ... (stage 33; after --focal-over-averages) there is no training and no step 1: S is the
# equal average of the given checkpoints (each an earlier stage's own step S), and step 2 on is unchanged.
# CAMERA_EVERY=1 in the environment (stage 34 on) runs the camera probe over all 48 held-out clip definitions instead
# of every 3rd (16), so that one clip weighs a third as much in the mean.
# PROBE_STEPS="625 750 875 1000" in the environment (stage 35 on) names the raw checkpoints of step 1 when a run is not
# 4,000 steps long (default: 2500 3000 3500 4000).
# PROBE_EMA="3000" in the environment (stage 38 on) adds the moving average of the weights (optim.ema_decay) kept in
# those checkpoints (step-N/ema) to step 1's candidates for S.
# AVERAGE_WEIGHTS="0.25 0.5 0.75 1" in the environment (stage 41 on) names the w of step 2 (default 0.25 0.5 0.75);
# w = 1 is S itself. Why: stage 39's raw checkpoints answered t_cam and its averages with the start did not.
# FOCAL_GATE=target in the environment (stage 44 on) makes step 3's synthetic condition "at most the 20% target"
# instead of "below the shipped figure". Why: stage 41's candidate was 5 points better than the start on held-out
# focal and 4 points worse than the shipped on the benchmark's 48 clips: on sets of 48 clips the median moves by more
# than training moves it, so beating the shipped figure is mostly the draw of clips; the target is what is promised.
# CAMERA_TOLERANCE=1.25 in the environment (stage 49 on) lets an average keep the camera when its held-out adjacent
# ATE mean is at most that many times the start's (default 1: not worse). Why: the promise is ATE <= 2x pycolmap's on
# the benchmark and the shipped model is at 1.36x; "not worse on the mean of 48 clips" was stricter than the promise
# and a few clips decided it (stage 48). The benchmark's eval still checks that no met target is lost.
# FOCAL_GATE=noninferior (stage 59 on, by hand in stage 59; see docs/training.md) makes step 3's synthetic condition
# "not worse than the shipped weights clip by clip": the upper end of the 95% paired-bootstrap interval of the mean
# per-clip focal error difference below 0.05 (tools/compare_evals.py --metric focal_error --margin 0.05). Why: the
# median of 48 clips moves by about 10 points with the draw of clips, and the shipped weights meet the target by 2.3.
# S_BY=focal in the environment (stage 58 on) chooses S differently in step 1: of the judged checkpoints whose held-out
# adjacent ATE mean is at most CAMERA_TOLERANCE times the start's, the one with the lowest held-out mean focal error
# (tools/measure_focal.py --held-out, measured on the second core as each checkpoint is written). Why: stage 57's S,
# chosen by camera, read focal worse than its later checkpoints on every held-out figure but the median, which moves
# by a few points with the draw of 48 clips; the mean error follows the fit's slope and spread.
# PAIRING=best in the environment (stage 73 on) scores each model's camera by the lowest held-out mean ATE over the
# pairings camera_probe reports (first, adjacent, graph) instead of adjacent's, and writes that pairing into the
# candidate's config.json (benchmarks/judge_pairing.py). Why: the pairing is chosen per model on held-out clips
# (stage 14), and models trained on learn long camera gaps that a chain of one-frame fits does not use (stage 71).
# GATE_SEED=N in the environment (stage 97 on; docs/training.md, "Gate sets drawn per judgment") replaces step 3:
# the candidate against the shipped weights (the start) on the gate set, the benchmark's 48 clip definitions from seeds
# N + i that no choice has seen: focal not worse clip by clip (margin 0.05, TUM within 20%), then pooled depth AbsRel
# (s&s) on its first 32 depth-probe clips lower with the upper end of the paired 95% interval below 0; a candidate that
# passes both gets the benchmark's eval, which must keep the met camera target ($J/verdict: SHIP or STOP). Why: the
# shipped weights were chosen through the benchmark's gates, so every later model met them on a selected draw (stage 95).
# HELD_OUT_FOCAL=mean in the environment (stage 100 on) makes the --focal-over-averages check compare the held-out
# mean focal error over the 48 clips (the mean of the per-clip paired differences) instead of the median. Why: stage
# 99's soup read 20.41% against the start's 20.35% by the median and -0.0045 [-0.0085, -0.0007] per clip, better on 32
# of 48; the median of 48 clips follows a few clips near the middle, and S_BY=focal already chose by the mean.
# HELD_OUT_FOCAL_MARGIN=m in the environment (stage 106 on) lets that check pass an average whose held-out focal
# statistic is at most the start's + m (e.g. 0.005, half a point) instead of strictly below it. Why: stage 105 was
# stopped there by 0.17-0.61 points while its depth read better; the gate set's clip-by-clip focal check still holds.
# BENCHMARK_NOT_WORSE="rpe_rot pc_l1" in the environment (stage 106 on) adds to the verdict: each named aggregate of the
# candidate's benchmark eval (lower is better) at most the shipped weights' (docs/model-card/eval-synthetic-dynamic-v1.json).
# Why: the average shipped by stage 104's rule, which weighed neither, read worse on both on most clips.
# DEPTH_BY=held-out in the environment (stage 109 on) makes --focal-over-averages choose, of the w that kept the camera
# and the held-out focal, the one whose pooled held-out depth AbsRel (s&s) is lowest (tools/depth_probe.py, its first
# DEPTH_BY_CLIPS held-out clips, default 16), and stop when none reads below the start's. Why: the largest such w was
# S itself in stage 108, which read no better than the start on the gate set's depth; the held-out clips are not the
# gate set's, so choosing on them leaves the gate set unseen. Caveat (stage 109): with 16 clips the pooled figure
# follows clip 34 (an outdoor clip at AbsRel (s&s) 7-8), so it chose on one clip there; stage 110's rule leaves it off.
# Run a copy of this file (cp benchmarks/judge_guarded_stage.sh $J/) when the tree may change while a judge runs:
# GATE_DELTA_MARGIN=m in the environment (stage 120 on) adds to the gate set's depth step: the candidate's delta<1.25
# (s&s) on the same 32 clips not worse than the start's by m (the lower end of the paired 95% interval above -m;
# tools/compare_evals.py --margin). Why: under the in-view aligned-depth recipe delta fell leg after leg while the
# pooled AbsRel gate passed (benchmark 0.715 -> 0.712 with stage 118; stage 119's gate -0.0057 [-0.0096, -0.0020]).
# GATE_OBJECTIVE=focal in the environment (stage 145 on) turns the gate set's two steps around for a stage that aims at
# the field of view: focal better than the start clip by clip (the upper end of the paired 95% interval of the mean
# per-clip focal error difference below 0, TUM within 20%), then depth non-inferior (pooled AbsRel (s&s): upper end
# below GATE_ABSREL_MARGIN, default 0.005; delta<1.25 by GATE_DELTA_MARGIN as before). Why: since stage 97 every rule
# asked for depth and only held focal, so a leg that found focal alone (stage 140: gate focal -0.0101 [-0.0161,
# -0.0042], AbsRel -0.0020 [-0.0081, +0.0021]) could not ship, while the median focal error (22.0%) is the nearest miss.
# bash reads a script as it goes, and an edit made meanwhile is read at shifted offsets (stage 95's gate judgment).
# Resumable (stage 41 on): every camera probe is kept per checkpoint in $J/probe-cache (the figures of one model do not
# depend on the others probed with it; the judged checkpoints and the start are probed on the second core while
# training runs), and a stopped judge started again skips each average, focal measurement and eval it already wrote
# (and resumes a stopped eval from the sequences it finished: d4rt eval --resume).
set -e
case "${GATE_OBJECTIVE:-depth}" in  # checked before anything runs, as HELD_OUT_FOCAL below
  depth|focal) ;;
  *) echo "judge_guarded_stage.sh: GATE_OBJECTIVE must be depth or focal, not '$GATE_OBJECTIVE'" >&2; exit 2 ;;
esac
case "${HELD_OUT_FOCAL:-median}" in  # checked before anything runs: inside focal_below a bad value would read as a FAIL
  median|mean) ;;
  *) echo "judge_guarded_stage.sh: HELD_OUT_FOCAL must be median or mean, not '$HELD_OUT_FOCAL'" >&2; exit 2 ;;
esac
EVERY=${CAMERA_EVERY:-3}
export AVERAGE_WEIGHTS=${AVERAGE_WEIGHTS:-0.25 0.5 0.75}
PROBE_STEPS=${PROBE_STEPS:-2500 3000 3500 4000}
N=${1:?usage: judge_guarded_stage.sh STAGE_NUMBER [--focal-over-averages [--soup-of CHECKPOINT ...]]}
EACH=${2:-}
SOUP=()
[ "${3:-}" = --soup-of ] && SOUP=("${@:4}")
cd /work/main
RUN=/work/runs/ship-tiny-stage$N
export J=/work/judge$N
probe_once() {  # CHECKPOINT: its held-out camera probe, once (the figures of a model do not depend on the others probed)
  local cache=$J/probe-cache/$(echo "$1" | tr / _).json
  [ -f $cache ] && return 0
  mkdir -p $J/probe-cache
  python tools/camera_probe.py $1 --frames 24 --time-stride 1 --every $EVERY --out $cache.part >> $J/judge.log 2>&1
  mv $cache.part $cache
}
reuse_probe() {  # FROM TO: TO is a byte copy of FROM; its cached probe is FROM's under TO's name (nothing to run)
  local from=$J/probe-cache/$(echo "$1" | tr / _).json to=$J/probe-cache/$(echo "$2" | tr / _).json
  [ -f $from ] && [ ! -f $to ] || return 0
  python -c "import json, sys; d = json.load(open(sys.argv[1])); d['models'] = {sys.argv[4]: d['models'][sys.argv[3]]}
json.dump(d, open(sys.argv[2], 'w'), indent=1)" $from $to "$1" "$2"
}
probe_merged() {  # OUT CHECKPOINT...: one probe JSON over the given checkpoints, from their cached probes
  local out=$1; shift
  for c in "$@"; do probe_once $c; done
  python - $out "$@" <<'P'
import json, os, sys
out, checkpoints = sys.argv[1], sys.argv[2:]
cache = [json.load(open(f"{os.environ['J']}/probe-cache/{c.replace('/', '_')}.json")) for c in checkpoints]
head = {k: v for k, v in cache[0].items() if k != "models"}
assert all({k: v for k, v in c.items() if k != "models"} == head for c in cache), "probes made with other settings"
json.dump(head | {"models": {c: p["models"][c] for c, p in zip(checkpoints, cache)}}, open(out, "w"), indent=1)
P
}
focal_once() {  # measure_focal.py ARGS ... --out FILE: skipped when FILE exists (a judge resumed after a stop)
  [ -f "${@: -1}" ] || python tools/measure_focal.py "$@" >> $J/judge.log 2>&1
}
focal_file() {  # CHECKPOINT (a judged one of $RUN): where its held-out focal is kept, focal-held-out-step-N[-ema].json
  echo $J/focal-held-out-$(echo "${1#$RUN/checkpoints/}" | tr / -).json
}
focal_of_checkpoint() { focal_once --held-out --checkpoint $1 --out $(focal_file $1); }  # once
if [ ${#SOUP[@]} -gt 0 ]; then
  S=("${SOUP[@]}")
  echo "S = the equal average of ${SOUP[*]} $(date -u)" >> $J/judge.log
else
  CK=""
  for s in $PROBE_STEPS; do CK="$CK $(printf "$RUN/checkpoints/step-%08d" "$s")"; done
  for s in ${PROBE_EMA:-}; do CK="$CK $(printf "$RUN/checkpoints/step-%08d/ema" "$s")"; done
  # While training runs, the second core probes each judged checkpoint as soon as it is written (checkpoints appear
  # atomically) and the start, so that little is left once training ends; the rule does not change.
  # Training has ended when every judged checkpoint is written: a run paused by SIGTERM (to run tests alone) and
  # resumed later is waited for, not judged early.
  all_written() { for c in $CK; do [ -f $c/model.safetensors ] || return 1; done; }
  until all_written; do
    for c in $J/start $CK; do [ -f $c/model.safetensors ] && probe_once $c; done
    if [ "${S_BY:-camera}" = focal ]; then
      for c in $CK; do [ -f $c/model.safetensors ] && focal_of_checkpoint $c; done
    fi
    sleep 20
  done
  [ -f $J/camera-probe-24-frames.json ] || echo "training ended $(date -u)" >> $J/judge.log
  probe_merged $J/camera-probe-24-frames.json $CK
  if [ "${S_BY:-camera}" = focal ]; then
    for c in $CK; do focal_of_checkpoint $c; done
    S=$(python - $(for c in $CK; do echo $c=$(focal_file $c); done) 2>> $J/judge.log <<'P'
import json, os, sys
sys.path.insert(0, 'benchmarks')
from judge_pairing import camera_ate
J = os.environ['J']
ate = lambda d, k: camera_ate(d['models'][k])
start = json.load(open(f"{J}/probe-cache/{(J + '/start').replace('/', '_')}.json"))
limit = float(os.environ.get('CAMERA_TOLERANCE', '1')) * ate(start, J + '/start')
d = json.load(open(J + '/camera-probe-24-frames.json'))
focal_files = dict(arg.split('=', 1) for arg in sys.argv[1:])  # checkpoint -> its held-out focal JSON
kept = [c for c in focal_files if ate(d, c) <= limit]
error = {c: json.load(open(focal_files[c]))['synthetic-held-out']['mean_focal_error'] for c in kept}
for c in kept:
    print(f"{c}: held-out adjacent ATE {ate(d, c):.4f} (limit {limit:.4f}), mean focal error {error[c]:.4f}",
          file=sys.stderr)
print(min(kept, key=error.get) if kept else 'none')
P
)
    [ "$S" = none ] && { echo "stopped: no judged checkpoint kept the start's camera" >> $J/judge.log; exit 0; }
  else
    S=$(python -c "
import json, os
d=json.load(open(os.environ['J'] + '/camera-probe-24-frames.json'))
import sys; sys.path.insert(0, 'benchmarks'); from judge_pairing import camera_ate
print(min(d['models'], key=lambda k: camera_ate(d['models'][k])))")
  fi
  echo "S=$S $(date -u)" >> $J/judge.log
fi
# Every average carries the start's motion-mask threshold (an inference setting measured for the shipped weights;
# runs from older weights may carry the default), so averaging never stops at it.
MOTION=$(python -c "import json; from d4rt.config import MOTION_THRESHOLD as m; print(json.load(open('$J/start/config.json')).get('motion_threshold', m))")
for w in $AVERAGE_WEIGHTS; do
  if [ -f $J/avg-$w/model.safetensors ]; then continue  # made by an earlier, interrupted judge
  elif [ "$w" = 1 ] && [ ${#S[@]} = 1 ]; then  # S itself (average_weights takes positive weights only)
    mkdir -p $J/avg-1 && cp ${S[0]}/config.json ${S[0]}/model.safetensors $J/avg-1/ && reuse_probe ${S[0]} $J/avg-1
  elif [ "$w" = 1 ]; then
    python tools/average_weights.py ${S[@]} --weights $(python -c "print(*[1] * ${#S[@]})") --out $J/avg-1 \
      --motion-threshold $MOTION >> $J/judge.log 2>&1
  else
    # The start may be a shipped model whose judge chose another pairing than the run's; the probe scores every
    # pairing and PAIRING=best writes the candidate's own, so the averages take the training recipe's.
    python tools/average_weights.py $J/start ${S[@]} --pose-pairs adjacent --motion-threshold $MOTION \
      --weights $(python -c "print(1 - $w, *[$w / ${#S[@]}] * ${#S[@]})") --out $J/avg-$w >> $J/judge.log 2>&1
  fi
done
probe_merged $J/camera-probe-candidates-24-frames.json $J/start $(for w in $AVERAGE_WEIGHTS; do echo $J/avg-$w; done)
W=$(python -c "
import json, os
J=os.environ['J']
d=json.load(open(J + '/camera-probe-candidates-24-frames.json'))['models']
import sys; sys.path.insert(0, 'benchmarks'); from judge_pairing import camera_ate
ate={k: camera_ate(v) for k, v in d.items()}
tolerance=float(os.environ.get('CAMERA_TOLERANCE', '1'))
ok=[w for w in sorted(os.environ['AVERAGE_WEIGHTS'].split(), key=float, reverse=True)
    if ate[J + '/avg-' + w] <= tolerance * ate[J + '/start']]
print(' '.join(ok) if ok else 'none')")
echo "w kept the camera (tolerance ${CAMERA_TOLERANCE:-1}x the start): $W $(date -u)" >> $J/judge.log
[ "$W" = none ] && { echo "stopped: no average keeps the start's camera" >> $J/judge.log; exit 0; }
focal_below() {  # NEW REF KEY LABEL [STAT [MARGIN]]: exit 0 when NEW's synthetic STAT (median or mean, under KEY) is
  # below REF's (a focal JSON: below it, or at most MARGIN above it when MARGIN > 0; a number: at most it), TUM within 20%
  python - "$@" <<'P' >> $J/judge.log
import json, sys
new, ref, key, label = sys.argv[1:5]
stat = f"{sys.argv[5] if len(sys.argv) > 5 else 'median'}_focal_error"
margin = float(sys.argv[6]) if len(sys.argv) > 6 else 0.0
n = json.load(open(new))
a, t = n[key][stat], n["tum-fr3-long-office-household"]["relative_error"]
try:  # a number is a target to meet
    b = float(ref); below = a <= b
except ValueError:  # a file is a model to beat (or to stay within MARGIN of)
    b = json.load(open(ref))[key][stat]; below = a <= b + margin if margin > 0 else a < b
ok = below and abs(t) <= 0.20
within = f" + {margin:.4f}" if margin > 0 else ""
print(f"{label}: synthetic {stat.split('_')[0]} {a:.4f} vs {b:.4f}{within}, TUM {t:+.4f} -> {'PASS' if ok else 'FAIL'}")
sys.exit(0 if ok else 1)
P
}
if [ "$EACH" = --focal-over-averages ]; then
  focal_once --held-out --checkpoint $J/start --out $J/focal-held-out-start.json
  C=none
  PASSED=""
  for w in $W; do
    focal_once --held-out --checkpoint $J/avg-$w --out $J/focal-held-out-avg-$w.json
    if focal_below $J/focal-held-out-avg-$w.json $J/focal-held-out-start.json synthetic-held-out \
        "held-out focal, w = $w against the start" ${HELD_OUT_FOCAL:-median} ${HELD_OUT_FOCAL_MARGIN:-0}; then
      PASSED="$PASSED $w"
      [ "${DEPTH_BY:-}" = held-out ] || { C=$w; break; }
    fi
  done
  if [ "${DEPTH_BY:-}" = held-out ] && [ -n "$PASSED" ]; then
    # Of the w that kept camera and held-out focal, the one whose pooled held-out depth AbsRel (s&s) is lowest, and
    # below the start's (none: stop before the gate set). Two probes at a time, one thread each.
    depth_file() { echo $J/depth-held-out-$1.json; }
    for m in start $(for w in $PASSED; do echo avg-$w; done); do
      [ -f $(depth_file $m) ] || python tools/depth_probe.py $J/$m --clips ${DEPTH_BY_CLIPS:-16} \
        --out $(depth_file $m) > $J/depth-held-out-$m.log 2>&1 &
      [ $(jobs -rp | wc -l) -ge 2 ] && wait -n
    done
    wait
    C=$(python - $J/start $(depth_file start) $(for w in $PASSED; do echo $J/avg-$w $(depth_file avg-$w); done) \
        2>> $J/judge.log <<'P'
import json, sys
pairs = list(zip(sys.argv[1::2], sys.argv[2::2]))  # (checkpoint, its held-out depth probe); the start first
absrel = {c: json.load(open(f))["models"][c]["abs_rel[scale&shift]"] for c, f in pairs}
start = pairs[0][0]
for c, a in absrel.items():
    print(f"held-out depth AbsRel (s&s) {a:.4f}: {c}", file=sys.stderr)
best = min((c for c, _ in pairs[1:]), key=absrel.get)
print(best.rsplit("avg-", 1)[1] if absrel[best] < absrel[start] else "none")
P
)
  fi
  echo "w=$C $(date -u)" >> $J/judge.log
  [ "$C" = none ] && { echo "stopped: no average that kept the camera beat the start's held-out focal$([ -n "${PASSED:-}" ] \
    && echo " and depth")" >> $J/judge.log; exit 0; }
  W=$C
else
  W=${W%% *}  # the rule of stages 29-31: the largest w that kept the camera
  echo "w=$W $(date -u)" >> $J/judge.log
fi
if [ ! -d $J/candidate ]; then
  cp -r $J/avg-$W $J/candidate
  # PAIRING=best: the candidate carries the pairing that gave its held-out figure (d4rt eval uses the model's own)
  [ "${PAIRING:-adjacent}" = best ] && python benchmarks/judge_pairing.py $J/camera-probe-candidates-24-frames.json \
    $J/avg-$W $J/candidate/config.json >> $J/judge.log
fi
focal_once --checkpoint $J/candidate --out $J/focal.json
tum_within() {  # FOCAL_JSON: exit 0 when its TUM fx is within 20% of the published one
  python -c "import json, sys; sys.exit(abs(json.load(open('$1'))['tum-fr3-long-office-household']['relative_error']) > 0.20)"
}
SHIPPED_FOCAL=/work/main/docs/model-card/focal.json
GATE=$J/gate
if [ -n "${GATE_SEED:-}" ]; then
  # GATE_SEED (stage 97 on; docs/training.md, "Gate sets drawn per judgment"): both comparisons with the shipped
  # weights ($J/start) are made on the gate set, the 48 clip definitions of seeds GATE_SEED + i, which no choice has
  # seen; the benchmark's focal above is reported and no longer decides.
  GATE=$J/gate-$GATE_SEED
  G=$J/gate-$GATE_SEED-
  if [ ! -f $GATE ]; then
    focal_once --gate-seed $GATE_SEED --checkpoint $J/start --out ${G}focal-start.json
    focal_once --gate-seed $GATE_SEED --checkpoint $J/candidate --out ${G}focal-candidate.json
    if [ "${GATE_OBJECTIVE:-depth}" = focal ]; then  # the stage aims at focal: better focal, depth non-inferior
      FOCAL_MARGIN=0; ABSREL_MARGIN=${GATE_ABSREL_MARGIN:-0.005}
      FOCAL_WORDS="better than the shipped weights clip by clip (upper end below 0)"
      DEPTH_WORDS="not worse by ${ABSREL_MARGIN} (upper end below it)"
    else
      FOCAL_MARGIN=0.05; ABSREL_MARGIN=0
      FOCAL_WORDS="not worse than the shipped weights clip by clip (margin 0.05)"
      DEPTH_WORDS="lower, upper end below 0"
    fi
    echo "gate set $GATE_SEED, focal: $FOCAL_WORDS, TUM within 20%" >> $J/judge.log
    echo FAIL > $GATE.part
    if python tools/compare_evals.py ${G}focal-start.json ${G}focal-candidate.json --metric focal_error \
         --margin $FOCAL_MARGIN >> $J/judge.log && tum_within ${G}focal-candidate.json; then
      echo "gate set $GATE_SEED, depth: pooled AbsRel (s&s) on its first 32 depth clips $DEPTH_WORDS" >> $J/judge.log
      for m in start candidate; do  # one thread each, side by side
        [ -f ${G}depth-$m.json ] || python tools/depth_probe.py $J/$m --gate-seed $GATE_SEED --clips 32 \
          --out ${G}depth-$m.json > ${G}depth-$m.log 2>&1 &
      done
      wait
      DELTA_OK=yes  # reported; with GATE_DELTA_MARGIN it decides too (non-inferior at that margin)
      python tools/compare_evals.py ${G}depth-start.json ${G}depth-candidate.json --methods $J/start $J/candidate \
        --metric 'delta<1.25[scale&shift]' ${GATE_DELTA_MARGIN:+--margin $GATE_DELTA_MARGIN} >> $J/judge.log \
        || DELTA_OK=no
      python tools/compare_evals.py ${G}depth-start.json ${G}depth-candidate.json --methods $J/start $J/candidate \
        --metric 'abs_rel[scale&shift]' --margin $ABSREL_MARGIN >> $J/judge.log && [ $DELTA_OK = yes ] && echo PASS > $GATE.part
    fi
    mv $GATE.part $GATE
  fi
  echo "gate set $GATE_SEED: $(cat $GATE)" >> $J/judge.log
elif [ "${FOCAL_GATE:-shipped}" = noninferior ]; then
  echo "focal gate: not worse than the shipped weights clip by clip (margin 0.05), TUM within 20%" >> $J/judge.log
  # The 20% target is still reported (median below); it no longer decides.
  focal_below $J/focal.json 0.20 synthetic-dynamic-v1 "the 20% target (reported, not the gate)" || true
  if python tools/compare_evals.py $SHIPPED_FOCAL $J/focal.json --metric focal_error --margin 0.05 >> $J/judge.log &&
     tum_within $J/focal.json
  then echo PASS > $GATE; else echo FAIL > $GATE; fi
  echo "focal gate: $(cat $GATE)" >> $J/judge.log
else
  if [ "${FOCAL_GATE:-shipped}" = target ]; then
    GATE_REF=0.20; GATE_LABEL="focal gate against the 20% target"
  else
    GATE_REF=$SHIPPED_FOCAL; GATE_LABEL="focal gate against shipped"
  fi
  if focal_below $J/focal.json $GATE_REF synthetic-dynamic-v1 "$GATE_LABEL"
  then echo PASS > $GATE; else echo FAIL > $GATE; fi
fi
if [ "$(cat $GATE)" = PASS ] && [ ! -f $J/eval.json ]; then
  d4rt eval --benchmark synthetic-dynamic-v1 --checkpoint $J/candidate --baseline oracle --baseline constant-depth \
     --baseline static-camera --baseline constant-velocity \
     --out $J/eval.json --resume --no-progress > $J/eval.md 2>> $J/judge.log
  echo "eval done $(date -u)" >> $J/judge.log
fi
if [ -n "${GATE_SEED:-}" ] && [ -f $J/eval.json ]; then
  # The benchmark must keep the met camera target (ATE at most 2x pycolmap's on the clips both posed, every clip posed).
  python - $J/eval.json > $J/verdict <<'P'
import json, os, sys
sys.path.insert(0, "tools")
from model_card import camera_target, with_reference_methods
new = json.load(open(sys.argv[1]))
ratio, kept = camera_target(with_reference_methods(new))
shipped = json.load(open("docs/model-card/eval-synthetic-dynamic-v1.json"))
aggregate = lambda result: next(m for m in result["methods"] if m["name"] == "d4rt")["aggregate"]
held = []  # BENCHMARK_NOT_WORSE: metrics (lower is better) whose mean may not rise above the shipped weights'
for metric in os.environ.get("BENCHMARK_NOT_WORSE", "").split():
    a, b = aggregate(new)[metric], aggregate(shipped)[metric]
    held.append(f"{metric} {a:.4g} vs shipped {b:.4g} ({'kept' if a <= b else 'worse'})")
    kept = kept and a <= b
print(f"{'SHIP' if kept else 'STOP'}: camera ATE {ratio:.2f}x pycolmap's (the target: at most 2x with every clip posed)"
      + "".join(f"; {h}" for h in held))
P
  echo "verdict: $(cat $J/verdict)" >> $J/judge.log
fi
