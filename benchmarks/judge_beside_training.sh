#!/bin/bash
# A stage's judge (benchmarks/judge_guarded_stage.sh, by the rule its config's header states) run beside its training,
# so that the verdict comes about 40 minutes after the training ends instead of 80 on a 2-core CPU. Nothing here
# changes what the rule decides: every file it writes is one the judge would write itself, by the same command and
# under the same name, and the judge skips the steps whose files exist.
#   pre     the start's measurements the judge needs (held-out camera probe, held-out focal, the gate set's focal and
#           depth), made while the training runs (the depth probe takes about 26 minutes on one core);
#   launch  waits for "trained to step STEPS" in every log of RUN_LOG, applies the stop rule of stages 104 on to
#           every run of RUN_DIR (mean logged confidence over steps 201-400 of its metrics.jsonl at least 0.6, else no
#           judge), then runs the judge command given after "--" (the one in the config's header). RUN_LOG and
#           RUN_DIR may each name several, space-separated, in the same order (a soup's sibling legs);
#   side    once the judge has written avg-1, probes it on the second core; once the judge has chosen its candidate,
#           begins the benchmark eval with the judge's own arguments (d4rt eval --resume), and stops it at the gate
#           set's verdict so that the judge's own eval, if it comes, resumes from its rows.
# Environment: J (the judge folder, holding start/, a copy of the weights shipped when it is judged) and GATE_SEED;
# launch also RUN_LOG, RUN_DIR and STEPS (and POLL, the seconds between looks at the logs, default 20). Run from the
# repository root, each part as its own background job, e.g. for stage 122 (the launch's judge command copied from
# configs/ship-tiny-cpu-stage122-aligned-in-view-second-leg.yaml):
#   export J=/work/judge122 GATE_SEED=11122000 RUN_LOG=/work/runs/stage122.log RUN_DIR=/work/runs/ship-tiny-stage122
#   export STEPS=1600 OMP_NUM_THREADS=1
#   mkdir -p $J && cp -r src/d4rt/assets/d4rt-tiny $J/start && cp benchmarks/judge_guarded_stage.sh $J/
#   nohup setsid bash benchmarks/judge_beside_training.sh pre > $J/pre.log 2>&1 &
#   nohup setsid bash benchmarks/judge_beside_training.sh side > $J/side.log 2>&1 &
#   nohup setsid bash benchmarks/judge_beside_training.sh launch -- env GATE_DELTA_MARGIN=0.01 PAIRING=best ... \
#     bash $J/judge_guarded_stage.sh 122 --focal-over-averages --soup-of ... > $J/launch.out 2>&1 &
# A start's held-out files from an earlier judge of the same bytes may be copied into $J first (probe-cache entry and
# focal-held-out-start.json, with that judge's folder name replaced by $J's in them); pre then skips them.
set -eu
: "${J:?set J to the judge folder}" "${GATE_SEED:?set GATE_SEED to the gate set of the config header}"
[ -d "$J/start" ] || { echo "no $J/start: copy the shipped weights there first" >&2; exit 2; }
cache() { echo "$J/probe-cache/$(echo "$1" | tr / _).json"; }  # where the judge keeps a checkpoint's camera probe
G=$J/gate-$GATE_SEED-

case "${1:-}" in
pre)
  mkdir -p $J/probe-cache
  c=$(cache $J/start)
  [ -f $c ] || { python tools/camera_probe.py $J/start --frames 24 --time-stride 1 --every 1 --out $c.part \
                 && mv $c.part $c; }
  echo "start probed $(date -u)"
  [ -f $J/focal-held-out-start.json ] || python tools/measure_focal.py --held-out --checkpoint $J/start \
    --out $J/focal-held-out-start.json
  echo "held-out focal done $(date -u)"
  [ -f ${G}focal-start.json ] || python tools/measure_focal.py --gate-seed $GATE_SEED --checkpoint $J/start \
    --out ${G}focal-start.json
  echo "gate focal done $(date -u)"
  [ -f ${G}depth-start.json ] || python tools/depth_probe.py $J/start --gate-seed $GATE_SEED --clips 32 \
    --out ${G}depth-start.json > ${G}depth-start.log 2>&1
  echo "gate depth done $(date -u)"
  ;;
launch)
  : "${RUN_LOG:?}" "${RUN_DIR:?}" "${STEPS:?}"
  [ "${2:-}" = -- ] && [ $# -gt 2 ] || { echo "usage: judge_beside_training.sh launch -- JUDGE COMMAND" >&2; exit 2; }
  shift 2
  read -r -a logs <<< "$RUN_LOG"; read -r -a dirs <<< "$RUN_DIR"
  [ ${#logs[@]} -gt 0 ] && [ ${#logs[@]} = ${#dirs[@]} ] || {
    echo "RUN_LOG names ${#logs[@]} logs and RUN_DIR ${#dirs[@]} runs: name each leg's log and run, in one order" >&2
    exit 2; }
  for log in "${logs[@]}"; do until grep -q "trained to step $STEPS" "$log" 2>/dev/null; do sleep ${POLL:-20}; done; done
  rule=0
  python - "${dirs[@]}" <<'P' > $J/stop-rule.txt 2>> $J/launch.log || rule=$?
import json, sys
stop = False
for run in sys.argv[1:]:
    rows = [json.loads(line) for line in open(f"{run}/metrics.jsonl")]
    c = [r["loss/confidence_mean"] for r in rows if 201 <= r["step"] <= 400 and "loss/confidence_mean" in r]
    if not c:
        sys.exit(f"no loss/confidence_mean logged over steps 201-400 in {run}/metrics.jsonl: stop rule cannot be read")
    mean = sum(c) / len(c)
    stop |= mean < 0.6
    print(f"{run}: mean confidence over steps 201-400: {mean:.3f} ({len(c)} logged steps) -> "
          f"{'judge' if mean >= 0.6 else 'stop'}")
sys.exit(4 if stop else 0)  # 4: the rule stops; any other failure is an error (its message in launch.log)
P
  [ $rule = 4 ] && { echo "stop rule: stop $(date -u)" >> $J/launch.log; exit 0; }
  [ $rule = 0 ] || { echo "stop rule could not be read (above): no judge $(date -u)" >> $J/launch.log; exit 2; }
  echo "judge from $(date -u)" >> $J/launch.log
  status=0
  "$@" > $J/judge.out 2>&1 || status=$?
  echo "judge ended rc=$status $(date -u)" >> $J/launch.log
  ;;
side)
  until [ -f $J/avg-1/model.safetensors ]; do sleep 10; done
  c=$(cache $J/avg-1)
  [ -f $c ] || { python tools/camera_probe.py $J/avg-1 --frames 24 --time-stride 1 --every 1 --out $c.side.part \
                 > $J/side-probe.log 2>&1 && mv $c.side.part $c; }
  echo "avg-1 probed $(date -u)"
  until grep -qs "candidate pairing\|stopped" $J/judge.log; do sleep 10; done
  grep -q "stopped" $J/judge.log && { echo "judge stopped; no eval"; exit 0; }
  echo "speculative eval from $(date -u)"
  d4rt eval --benchmark synthetic-dynamic-v1 --checkpoint $J/candidate --baseline oracle --baseline constant-depth \
    --baseline static-camera --baseline constant-velocity \
    --out $J/eval.json --resume --no-progress > $J/eval-side.md 2>> $J/side-eval.log &
  eval_pid=$!
  until grep -q "gate set $GATE_SEED: " $J/judge.log; do sleep 5; kill -0 $eval_pid 2>/dev/null || break; done
  if kill -0 $eval_pid 2>/dev/null; then
    kill $eval_pid; wait $eval_pid || true
    rm -f $J/eval.json  # a stopped eval writes none; the judge writes its own
    echo "speculative eval stopped at the gate's verdict $(date -u)"
  else
    echo "speculative eval finished before the gate $(date -u)"
  fi
  ;;
*)
  echo "usage: J=... GATE_SEED=... judge_beside_training.sh pre|side|launch -- JUDGE COMMAND" >&2; exit 2 ;;
esac
