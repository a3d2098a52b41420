#!/bin/bash
# A lent GPU's 30 minutes, spent as the project asks: (1) the small preset trained from scratch with the shipped
# recipe (configs/small-gpu-best.yaml), its weights brought back; (2) the giant bench for the README.
# The device tool runs one command for at most 10 minutes and gives an idle machine back after 30 s, so the
# lease is three calls made back to back, each from the repository root on the GPU machine:
#   bash benchmarks/gpu_session.sh start    # measures the speed inside the warm-up, sets the run's length,
#                                           # leaves training running (setsid) and returns a snapshot at ~9.5 min
#   bash benchmarks/gpu_session.sh wait     # returns a second snapshot when the run ends (~16 min)
#   bash benchmarks/gpu_session.sh finish   # waits for the last step, runs the giant bench, returns everything
# A 15-minute lease (the machine's start counted) has room for two calls instead (docs/training.md):
#   TRAIN_S=300 PART_A_S=110 CALL_S=570 bash benchmarks/gpu_session.sh lease   # train, snapshot, start the bench
#   (PROBE_S=60 first profiles one GPU step, batch 1, into probe.txt; INIT_FROM=DIR continues from a model directory;
#   BENCH=0 skips the bench, for a lease that only trains; ECHO=E draws E samples from each rendered clip, default 2)
#   (CONFIG=configs/tiny-gpu-continue.yaml INIT_FROM=src/d4rt/assets/d4rt-tiny: the shipped tiny model trained on
#   instead, a lease whose product can ship; docs/training.md "A lease that can ship")
#   bash benchmarks/gpu_session.sh collect  # only if the bench was still running: waits WAIT_S (150 s) for it
# Each call writes into $OUT: weights.tar.part-aa, -ab, ... (model.safetensors, config.json, metrics.jsonl,
# train_config.yaml, hardware.json and the newest checkpoint of the run, split under the tool's 16 MiB per file),
# progress.txt, and at the end bench-gpu.json.
# Join them here:  mkdir -p W && cat FILES_AT/weights.tar.part-* | tar -x -C W   (W is then a checkpoint).
# TRAIN_S (default 900) is the training's wall budget from the start of `start`; the rest of the 1,800 s goes to
# the machine's start (about 1.5 min, counted), the transfers between calls and the bench, which needs about 8 minutes
# whatever the device: its Tab. 3 search runs trials of up to T / FPS wall time each (48 s at 1 FPS for 48 frames). A run the machine
# could not keep (`wait` or `finish` on a fresh machine) says so and brings back nothing new: the last snapshot
# came back with the call before.
set -euo pipefail
PHASE=${1:?usage: gpu_session.sh start|wait|finish}
TRAIN_S=${TRAIN_S:-900}
G=/tmp/d4rt-gpu
RUN=$G/run
CONFIG=${CONFIG:-configs/small-gpu-best.yaml}  # another config: e.g. a small one for a dry run on a CPU
export PYTHONPATH=$PWD/src${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
# The GPU image has torch and every core dependency but PyAV, which training and the bench never import; d4rt
# runs from src/ (a dry run here may put a sitecustomize that blocks PyAV on PYTHONPATH, as the docs describe).
OUT=${OUT:?OUT must name the folder whose files come back}

now() { date +%s; }
elapsed() { echo $(( $(now) - $(cat $G/t0) )); }
running() { [ -f $G/pid ] && kill -0 "$(cat $G/pid)" 2>/dev/null; }

snapshot() {  # the run's latest weights (written at every checkpoint) and log, in pieces the tool brings back
  rm -f $OUT/weights.tar.part-*
  if [ -f $RUN/model.safetensors ]; then
    # With them the newest whole checkpoint (its weights are the top-level file's hard link; the optimiser adds about
    # 37 MB for the tiny preset) and the machine's description, so that tools/training_summary.py can describe the
    # run and `d4rt train --resume` can continue it after the lease (the sixth lease brought back neither).
    LAST=$(cd $RUN && ls -d checkpoints/step-* 2>/dev/null | tail -n 1)
    python3 -c 'import json, os, shutil, subprocess, torch
smi = shutil.which("nvidia-smi") and subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                                                    capture_output=True, text=True).stdout.strip()
gpu = smi.splitlines()[0] if smi else torch.cuda.get_device_name() if torch.cuda.is_available() else None
print(json.dumps({"gpu": gpu, "logical_cpus": os.cpu_count(), "torch": torch.__version__, "cuda": torch.version.cuda}))' \
      > $RUN/hardware.json
    # A call brings back at most 64 MiB in 8 files: a larger model's checkpoint (the grown enc10's weights and optimiser
    # state, 77 MB) does not fit, and then the weights, config and log come back alone (not resumable after the lease).
    FILES=(model.safetensors config.json metrics.jsonl train_config.yaml hardware.json)
    if [ -n "$LAST" ] && [ "$(tar -C $RUN -cf - "${FILES[@]}" $LAST | wc -c)" -gt $(( 60 * 1024 * 1024 )) ]; then
      echo "checkpoint $LAST too large to bring back (over 60 MiB with the weights): weights and log only"
      LAST=
    fi
    tar -C $RUN -cf - "${FILES[@]}" $LAST | split -b 15m - $OUT/weights.tar.part-
  fi
  { echo "phase $PHASE at ${1:-?} s"; tail -n 3 $RUN/metrics.jsonl 2>/dev/null || true
    tail -n 5 $G/train-*.log 2>/dev/null || true; } > $OUT/progress.txt
  cat $OUT/progress.txt
}

stop_run() {  # past its budget: SIGTERM checkpoints the current step and exits 143
  if running; then
    echo "still running at $(elapsed) s: stopping it (SIGTERM writes a checkpoint)"
    kill -TERM "$(cat $G/pid)"
    while running; do sleep 2; done
  fi
}

return_bench() {  # the background bench's report so far (and its JSON once written) into $OUT
  cp $G/bench-gpu.txt $OUT/; cp $G/bench-gpu.json $OUT/ 2>/dev/null || true
  cat $G/bench-gpu.txt
}

sleep_until() {  # until $1 s after the start, or until the run ends
  while running && [ "$(elapsed)" -lt "$1" ]; do sleep 10; done
}

case $PHASE in
start)
  rm -rf $G && mkdir -p $G && now > $G/t0
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
  python3 -c "import torch, d4rt; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.is_available())"
  # Part A: up to 300 steps, inside the 500-step warm-up, whose learning rates do not depend on run.max_steps.
  # Each try is time-boxed (SIGTERM checkpoints the step it reached), so that this call ends inside the tool's
  # 10 minutes however slow a step is; a try counts if it logged 40 steps.
  part_a() {  # $1: the try's deadline (s after the start); then extra arguments for d4rt train
    local limit=$(( $1 - $(elapsed) )); shift
    [ $limit -gt 30 ] || limit=30  # (timeout 0 would mean none)
    rm -rf $RUN
    timeout -s TERM $limit python3 -m d4rt train --config $CONFIG --out $RUN --max-steps 300 \
      --no-progress "$@" > $G/train-a.log 2>&1 || true
    python3 -c "import json, sys; sys.exit(0 if max(json.loads(l)['step'] for l in open('$RUN/metrics.jsonl')) >= 40 else 1)" \
      2>/dev/null
  }
  EXTRA=()
  if ! part_a 330; then
    tail -n 20 $G/train-a.log
    echo "part A failed with clips rendered on the GPU; again with the CPU renderer"
    EXTRA=(--set data.dataset.render_device=cpu --set data.workers=$(( $(nproc) - 1 )))
    part_a 500 "${EXTRA[@]}" || { tail -n 40 $G/train-a.log; exit 1; }
  fi
  # Steps per second over the logged windows after the first third (workers and kernels warmed up).
  STEPS=$(python3 - "$RUN/metrics.jsonl" "$CONFIG" "$(elapsed)" "$TRAIN_S" <<'P'
import json, statistics, sys, yaml
rows = [json.loads(line) for line in open(sys.argv[1])]
config = yaml.safe_load(open(sys.argv[2]))
batch = config["data"]["batch_size"]
assert config["optim"]["warmup_steps"] >= 300, "part A must end inside the warm-up (optim.warmup_steps >= 300)"
last = rows[-1]["step"]
speed = statistics.median(r["throughput/clips_per_s"] for r in rows if r["step"] > last / 3) / batch
left = int(sys.argv[4]) - int(sys.argv[3]) - 60  # the resume's start-up
steps = max(600, last + int(speed * left))
print(steps)
print(f"part A: {last} steps, {speed:.2f} steps/s; the run will end at step {steps}", file=sys.stderr)
P
)
  setsid nohup python3 -m d4rt train --config $CONFIG --out $RUN --max-steps $STEPS --resume --no-progress \
    "${EXTRA[@]}" > $G/train-b.log 2>&1 < /dev/null &
  echo $! > $G/pid
  sleep_until 560
  snapshot "$(elapsed)"
  ;;
wait)
  [ -f $G/t0 ] || { echo "no run on this machine (it was replaced): the last snapshot came back with 'start'"; exit 2; }
  sleep_until $(( TRAIN_S + 60 ))
  snapshot "$(elapsed)"
  ;;
finish)
  [ -f $G/t0 ] || { echo "no run on this machine (it was replaced): the last snapshot came back with 'wait'"; exit 2; }
  sleep_until $(( TRAIN_S + 60 ))
  stop_run
  snapshot "$(elapsed)"
  # Its console report comes back too (bench-gpu.txt), whatever the time limit leaves of it.
  timeout 540 python3 -m d4rt bench --preset giant --device cuda --dtype bf16 --frames 48 --size 256 \
    --json $OUT/bench-gpu.json 2>&1 | tee $OUT/bench-gpu.txt || echo "bench ended with status $?"
  ;;
lease)  # a 15-minute lease in two calls: this one (<= 600 s) trains for TRAIN_S, snapshots, starts the bench
  # in the background and returns at CALL_S with the weights and the bench's first lines; `collect` returns the rest.
  rm -rf $G && mkdir -p $G && now > $G/t0
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
  CALL_S=${CALL_S:-570}; PART_A_S=${PART_A_S:-120}
  if [ "${PROBE_S:-0}" -gt 0 ]; then  # where a GPU step's time goes, batch 1, no loaders (counted in TRAIN_S)
    timeout $PROBE_S python3 benchmarks/bench_train.py --profile --device cuda --preset small --frames 24 \
      --size 128 --queries 2048 --crop-policy none --steps 16 --warmup 4 --profile-rows 12 2>&1 \
      | grep -v Warning | tee $OUT/probe.txt || echo "probe ended with status $?"
  fi
  rm -rf $RUN
  EXTRA=()
  # INIT_FROM: a model directory to continue from (an earlier lease's weights, carried; see docs/training.md)
  INIT=(); [ -z "${INIT_FROM:-}" ] || INIT=(--set model.init_from=$INIT_FROM)
  # ECHO=E: E samples per rendered clip (data echoing, stage 46). The loaders bound the run (the second lease);
  # echo 2 doubled the samples a second on an H200 (the third lease), so it is the default; ECHO=1 turns it off
  INIT+=(--set data.dataset.echo=${ECHO:-2})
  # Part A ends at the config's warm-up (at most 300 steps): past it the cosine would follow part A's own length, and
  # the resumed run's rates would jump back up (the sixth lease: a warm-up of 150 reached at 3 steps/s).
  PART_A_STEPS=$(python3 -c "import sys, yaml; print(min(300, yaml.safe_load(open(sys.argv[1]))['optim']['warmup_steps']))" $CONFIG)
  timeout -s TERM $PART_A_S python3 -m d4rt train --config $CONFIG --out $RUN --max-steps $PART_A_STEPS --no-progress \
    "${INIT[@]}" > $G/train-a.log 2>&1 || true
  if ! python3 -c "import json, sys; sys.exit(0 if max(json.loads(l)['step'] for l in open('$RUN/metrics.jsonl')) >= min(20, $PART_A_STEPS) else 1)" 2>/dev/null; then
    tail -n 20 $G/train-a.log
    echo "part A failed with clips rendered on the GPU; on with the CPU renderer"
    EXTRA=(--set data.dataset.render_device=cpu --set data.workers=$(( $(nproc) - 1 )))
    rm -rf $RUN
  fi
  EXTRA+=("${INIT[@]}")
  STEPS=$(python3 - "$RUN/metrics.jsonl" "$CONFIG" "$(elapsed)" "$TRAIN_S" <<'P'
import json, os, statistics, sys, yaml
config = yaml.safe_load(open(sys.argv[2]))
batch = config["data"]["batch_size"]
if os.path.exists(sys.argv[1]):
    rows = [json.loads(line) for line in open(sys.argv[1])]
    last = rows[-1]["step"]
    speed = statistics.median(r["throughput/clips_per_s"] for r in rows if r["step"] > last / 3) / batch
else:
    last, speed = 0, 1.0  # the CPU renderer's guess
left = int(sys.argv[4]) - int(sys.argv[3]) - 45  # the resume's start-up
steps = max(last + 100, last + int(speed * left))
print(steps)
print(f"part A: {last} steps, {speed:.2f} steps/s; the run will end at step {steps}", file=sys.stderr)
P
)
  setsid nohup python3 -m d4rt train --config $CONFIG --out $RUN --max-steps $STEPS --resume --no-progress \
    "${EXTRA[@]}" > $G/train-b.log 2>&1 < /dev/null &
  echo $! > $G/pid
  sleep_until $(( TRAIN_S + 20 ))
  stop_run
  snapshot "$(elapsed)"
  if [ "${BENCH:-1}" = 0 ]; then exit 0; fi  # BENCH=0: the whole lease trains (the bench's figures already taken)
  setsid nohup python3 -m d4rt bench --preset giant --device cuda --dtype bf16 --frames 48 --size 256 \
    --tolerance ${BENCH_TOLERANCE:-0.05} --no-progress --json $G/bench-gpu.json > $G/bench-gpu.txt 2>&1 < /dev/null &
  echo $! > $G/bench.pid
  while kill -0 "$(cat $G/bench.pid)" 2>/dev/null && [ "$(elapsed)" -lt $CALL_S ]; do sleep 5; done
  return_bench
  ;;
collect)  # the bench `lease` left running: waits up to WAIT_S for it, returns what it printed
  [ -f $G/bench.pid ] || { echo "no bench on this machine (it was replaced): its first lines came back with 'lease'"; exit 2; }
  END=$(( $(now) + ${WAIT_S:-150} ))
  while kill -0 "$(cat $G/bench.pid)" 2>/dev/null && [ "$(now)" -lt $END ]; do sleep 3; done
  return_bench
  ;;
*)
  echo "unknown phase $PHASE (start, wait, finish, lease or collect)"; exit 2 ;;
esac
