"""Stage 79's diagnosis of a checkpoint's full-video 3D tracks on held-out benchmark-like clips (seeds 7,000,000 +
index, as tools/occlusion_probe.py), tracked as ``d4rt eval`` tracks them.

    python benchmarks/results/stage79-correspondence-ab/track_diagnosis.py CHECKPOINT [--clips 16]

Per clip: the share of track points truly out of frame and the share the model puts there (its 3D points projected
through its own intrinsics); OA as the model calls visibility and with the true out-of-frame points called hidden
(an oracle bound); and, by the gap between the query frame and the target frame, the median distance (as a share of
the image) a point truly moves, the model moves it, and the model's error, all in normalised (u, v).
"""
import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from occlusion_probe import HELD_OUT_SEED, in_frame  # noqa: E402

from d4rt.evaluation.synthetic_benchmark import clip_specs  # noqa: E402
from d4rt.geometry.camera import project  # noqa: E402
from d4rt.model import D4RT  # noqa: E402

GAPS = (1, 3, 7, 12, 20)


def normalised_uv(points: np.ndarray, intrinsics: np.ndarray, height: int, width: int) -> np.ndarray:
    """points (T, N, 3) in each frame's camera, intrinsics (T, 3, 3) -> (T, N, 2) (u, v), pixel centres at i + 0.5."""
    with np.errstate(divide="ignore", invalid="ignore"):
        xy, _ = project(points, intrinsics[:, None])
    return np.stack([(xy[..., 0] + 0.5) / width, (xy[..., 1] + 0.5) / height], -1)


parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("checkpoint")
parser.add_argument("--clips", type=int, default=16)
args = parser.parse_args()
torch.set_num_threads(1)
model = D4RT.from_pretrained(args.checkpoint)
means = {}
for spec in [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()[::3][:args.clips]]:
    sequence = spec.render()
    tracks = sequence.tracks
    reconstruction = model.reconstruct(sequence.rgb)
    predicted = reconstruction.tracks(np.concatenate([tracks.query_frames[:, None], tracks.query_xy], 1))
    height, width = sequence.image_size
    true_uv = normalised_uv(tracks.points, sequence.intrinsics, height, width)
    model_uv = normalised_uv(predicted.points.transpose(1, 0, 2), reconstruction.cameras().intrinsics, height, width)
    start_uv = (tracks.query_xy + 0.5) / [width, height]  # (N, 2)
    truly_in = in_frame(tracks.points, sequence.intrinsics, sequence.image_size)
    model_in = np.isfinite(model_uv).all(-1) & ((model_uv >= 0) & (model_uv <= 1)).all(-1)
    called = predicted.visibility.T > 0.5
    row = {"true out of frame": 1 - truly_in.mean(), "model out of frame": 1 - model_in.mean(),
           "OA": np.mean(called == tracks.visible), "OA, true out-of-frame gate": np.mean((called & truly_in) == tracks.visible)}
    gap = np.abs(np.arange(len(true_uv))[:, None] - tracks.query_frames[None])
    for g in GAPS:
        m = gap == g
        if m.any():
            row[f"gap {g}: true move"] = np.nanmedian(np.linalg.norm((true_uv - start_uv)[m], axis=-1))
            row[f"gap {g}: model move"] = np.nanmedian(np.linalg.norm((model_uv - start_uv)[m], axis=-1))
            row[f"gap {g}: model error"] = np.nanmedian(np.linalg.norm((model_uv - true_uv)[m], axis=-1))
    print(spec.name, ", ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
    for k, v in row.items():
        means.setdefault(k, []).append(v)
print("mean over clips:", ", ".join(f"{k} {np.mean(v):.4f}" for k, v in means.items()))
