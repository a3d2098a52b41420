"""Cache a checkpoint's depth maps and the truth on the held-out depth-probe clips (tools/depth_probe.py's clips).

    python cache_depth.py CHECKPOINT OUT.npz [THREADS] [CLIPS]

Writes OUT.npz with CLIP/pred and CLIP/true, (T, H, W) float32 each, for depth_stretch.py.
"""
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from depth_probe import render_probe_clips  # noqa: E402

from d4rt.evaluation.predictions import d4rt_predictor  # noqa: E402

checkpoint, out = sys.argv[1], sys.argv[2]
torch.set_num_threads(int(sys.argv[3]) if len(sys.argv) > 3 else 1)
clips = int(sys.argv[4]) if len(sys.argv) > 4 else 16
predictor, arrays = d4rt_predictor(checkpoint), {}
with torch.no_grad():
    for sequence in render_probe_clips(clips):
        start = time.perf_counter()
        arrays[f"{sequence.name}/pred"] = predictor.predict(sequence, {"depth"}).depth.astype(np.float32)
        arrays[f"{sequence.name}/true"] = sequence.depth.astype(np.float32)
        print(sequence.name, f"{time.perf_counter() - start:.0f} s", flush=True)
np.savez_compressed(out, **arrays)
