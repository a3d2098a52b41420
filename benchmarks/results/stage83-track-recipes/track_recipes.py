"""Stage 83's comparison of ways to read full-video 3D tracks (in each frame's camera) out of one checkpoint, on the
held-out benchmark-like clips of tools/occlusion_probe.py (seeds 7,000,000 + index; the benchmark is not read).

    python benchmarks/results/stage83-track-recipes/track_recipes.py CHECKPOINT [--clips 16]

Recipes, for a track of pixel (u, v) of frame s, at frame k (frame "camera": the point in camera k):
  paper:   query (u, v, s, k, k)                       (the paper's recipe; what d4rt eval does)
  static:  query (u, v, s, s, k)                       (the point where it was at time s, seen from camera k)
  world:   query (u, v, s, k, s), moved into camera k by the model's own poses (Reconstruction.cameras())
  static+motion: query (u, v, s, s, k) + the paper query's `motion` output (displacement s -> k in camera k)
Visibility is the paper query's (probability > 0.5); "+gate" also calls hidden a point whose 3D position projects
outside the image through the model's own intrinsics (or lies behind the camera). Scored with the harness's
TAPVid-3D metrics (the benchmark's track scaling), per clip; means over clips and the paired bootstrap against paper.
Two bounds on where the paper recipe's APD3D is lost: "paper 2D only", its points moved along their own rays to the
true depth (TAPVid-3D's reproduce_2d scaling: only the 2D position is the model's), and "paper depth only", the true
points moved along their true rays to the model's depth (only the depth is the model's).
"""
import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from compare_evals import paired_bootstrap  # noqa: E402
from occlusion_probe import HELD_OUT_SEED, TRACK_SCALING, in_frame  # noqa: E402

from d4rt.evaluation.harness import track_intrinsics  # noqa: E402
from d4rt.evaluation.metrics.tracks import tapvid3d_metrics  # noqa: E402
from d4rt.evaluation.synthetic_benchmark import clip_specs  # noqa: E402
from d4rt.model import D4RT  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("checkpoint")
parser.add_argument("--clips", type=int, default=16)
args = parser.parse_args()
torch.set_num_threads(1)
model = D4RT.from_pretrained(args.checkpoint)
rows = []
for spec in [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()[::3][:args.clips]]:
    sequence = spec.render()
    tracks = sequence.tracks
    height, width = sequence.image_size
    frames = len(sequence.rgb)
    reconstruction = model.reconstruct(sequence.rgb)
    assert len(reconstruction.windows) == 1
    cameras = reconstruction.cameras()
    s = tracks.query_frames.astype(np.int64)  # (N,)
    n = len(s)
    uv = (tracks.query_xy + 0.5) / [width, height]  # (N, 2)
    answerer = reconstruction.source.window(0, frames)
    k = np.arange(frames)
    grid_s, grid_k = np.broadcast_to(s[None], (frames, n)), np.broadcast_to(k[:, None], (frames, n))  # (T, N)
    base = np.broadcast_to(uv[None], (frames, n, 2))

    def ask(t_tgt, t_cam):
        q = np.concatenate([base, grid_s[..., None], t_tgt[..., None], t_cam[..., None]], -1).reshape(-1, 5)
        answers = {}
        for i in range(0, len(q), 4096):
            out = answerer.query(q[i:i + 4096])
            for key in ("points", "visibility", "motion"):
                answers.setdefault(key, []).append(out[key].double().numpy())
        return {key: np.concatenate(v).reshape(frames, n, *v[0].shape[1:]) for key, v in answers.items()}

    paper = ask(grid_k, grid_k)
    static = ask(grid_s, grid_k)
    world = ask(grid_k, grid_s)
    # camera s -> camera k with the model's poses: x_k = inv(c2w_k) c2w_s x_s
    c2w = cameras.cam_to_world
    rel = np.linalg.inv(c2w)[k][:, None] @ c2w[s][None]  # (T, N, 4, 4)
    world_in_k = np.einsum("tnij,tnj->tni", rel[..., :3, :3], world["points"]) + rel[..., :3, 3]
    recipes = {"paper": paper["points"], "static": static["points"], "world": world_in_k,
               "static+motion": static["points"] + paper["motion"]}
    called = paper["visibility"] > 0.5
    row = {"clip": spec.name}
    for name, points in recipes.items():
        gate = in_frame(points, cameras.intrinsics, sequence.image_size)
        for suffix, vis in (("", called), ("+gate", called & gate)):
            m = tapvid3d_metrics(points, vis, tracks.points, tracks.visible, track_intrinsics(sequence),
                                 sequence.image_size, TRACK_SCALING)
            row[f"{name}{suffix} apd3d"], row[f"{name}{suffix} oa"] = m["apd3d"], m["oa"]
    # Where the paper recipe's APD3D is lost: its points with the true depth along their own rays (only the
    # direction, i.e. the 2D position, left to the model), and the true rays at the model's own depth z.
    for name, points, scaling in (("paper 2D only", paper["points"], "reproduce_2d"),
                                  ("paper depth only", tracks.points * (paper["points"][..., 2:] / tracks.points[..., 2:]),
                                   TRACK_SCALING)):
        m = tapvid3d_metrics(points, called, tracks.points, tracks.visible, track_intrinsics(sequence),
                             sequence.image_size, scaling)
        row[f"{name} apd3d"] = m["apd3d"]
    rows.append(row)
    print(spec.name, ", ".join(f"{key} {v:.4f}" for key, v in row.items() if key != "clip"), flush=True)
keys = [key for key in rows[0] if key != "clip"]
print("mean over clips:")
for key in keys:
    values = np.array([r[key] for r in rows])
    ref = np.array([r["paper " + key.split(" ")[-1]] for r in rows])
    line = f"  {key}: {values.mean():.4f}"
    if not key.startswith("paper "):
        b = paired_bootstrap(ref, values, np.ones_like(ref), lower_is_better=False)
        line += f"  vs paper {b['difference']:+.4f} [{b['low']:+.4f}, {b['high']:+.4f}]"
    print(line)
