#!/bin/bash
# benchmarks/gpu_session.sh rehearsed on a CPU, before a lent GPU's minutes are spent on it (about 5 minutes):
#   bash benchmarks/gpu_session_dry_run.sh
# The same three phases on a shrunken configs/small-gpu-best.yaml (tiny preset, 4 frames of 64x64, 2 clips a step,
# 64 queries), with PyAV blocked as on the GPU image and TRAIN_S=150. Without CUDA part A fails on render_device
# and the script's fallback (the CPU renderer) is what runs; `finish` ends with the bench's one-line CUDA error.
# Checks at the end: the returned pieces join into a checkpoint that loads.
#   bash benchmarks/gpu_session_dry_run.sh lease   # the 15-minute lease's two phases instead (about 2.5 minutes):
#                                                  # `lease` from a bfloat16 copy of the shipped model (INIT_FROM), then `collect`
set -euo pipefail
MODE=${1:-three}
D=$(mktemp -d /tmp/d4rt-dry-XXXX)
mkdir -p $D/site $D/W
cat > $D/site/sitecustomize.py <<'P'
import importlib.abc, sys
class BlockAV(importlib.abc.MetaPathFinder):  # the GPU image has no PyAV
    def find_spec(self, name, path, target=None):
        if name == "av" or name.startswith("av."):
            raise ImportError("PyAV is blocked in the dry run")
sys.meta_path.insert(0, BlockAV())
P
python3 - $D/dry.yaml <<'P'
import sys, yaml
c = yaml.safe_load(open("configs/small-gpu-best.yaml"))
c["model"]["preset"] = "tiny"
c["data"].update(batch_size=2, workers=1)
c["data"]["dataset"].update(frames=4, size=[64, 64], render_pixels=64 * 64)
c["data"]["dataset"]["sampler"]["num_queries"] = 64
c["run"].update(checkpoint_every=100)
yaml.safe_dump(c, open(sys.argv[1], "w"), sort_keys=False)
P
if [ "$MODE" = lease ]; then
  mkdir -p $D/init $D/out-lease $D/out-collect
  cp src/d4rt/assets/d4rt-tiny/config.json $D/init/
  python3 -c "
import sys
from safetensors.torch import load_file, save_file
save_file({k: v.bfloat16() for k, v in load_file(sys.argv[1]).items()}, sys.argv[2])
" src/d4rt/assets/d4rt-tiny/model.safetensors $D/init/model.safetensors
  PYTHONPATH=$D/site CONFIG=$D/dry.yaml INIT_FROM=$D/init TRAIN_S=90 PART_A_S=40 CALL_S=120 OUT=$D/out-lease \
    bash benchmarks/gpu_session.sh lease 2>&1 | cut -c1-160
  OUT=$D/out-collect WAIT_S=5 bash benchmarks/gpu_session.sh collect 2>&1 | cut -c1-160
  grep -q "init_from: $D/init" /tmp/d4rt-gpu/run/train_config.yaml && echo "the run started from INIT_FROM"
  LAST=out-lease
else
  for phase in start wait finish; do
    mkdir -p $D/out-$phase
    PYTHONPATH=$D/site CONFIG=$D/dry.yaml TRAIN_S=150 OUT=$D/out-$phase bash benchmarks/gpu_session.sh $phase \
      2>&1 | cut -c1-160
  done
  LAST=out-finish
fi
cat $D/$LAST/weights.tar.part-* | tar -x -C $D/W
PYTHONPATH=$PWD/src python3 -c "
import sys
from d4rt.model.weights import read_checkpoint
config, state = read_checkpoint(sys.argv[1])
print(f'joined weights: {len(state)} tensors, {sum(t.numel() for t in state.values()) / 1e6:.1f}M parameters: a checkpoint that loads')
" $D/W
tail -n 1 $D/W/metrics.jsonl | cut -c1-120
echo "dry run in $D"
