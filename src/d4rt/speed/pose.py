"""Camera-pose FPS: intrinsics and camera-to-world poses of every frame, from the video, per second.

The recipe is the one users call, ``model.reconstruct(video).cameras()`` (paper Sec. 2.1): encode the
clip, query a grid of every frame in its own camera and in the reference camera, fit intrinsics by
the pinhole median and poses by Umeyama. FPS = frames / wall time, encoder included. The comparison
with COLMAP on equal terms is :mod:`d4rt.speed.colmap_comparison`.
"""

from __future__ import annotations

import torch

from d4rt.speed.options import BenchOptions
from d4rt.speed.timing import best_time
from d4rt.reconstruction.reconstruction import DEFAULT_GRID, Reconstruction


def bench_pose(model, video: torch.Tensor, options: BenchOptions) -> dict:
    """Best wall time of the full camera recipe on ``video (T, H, W, 3)``; pose_fps = T / that time."""
    device = torch.device(options.device)
    frames = video.shape[0]

    grid = {} if options.pose_grid is None else {"grid": options.pose_grid}

    def run():
        return Reconstruction.from_model(model, video, progress=False, **grid).cameras()

    with options.autocast():
        seconds = best_time(run, device, options.repeats)
    return {"pose_s": seconds, "pose_fps": frames / seconds, "pose_frames": frames,
            "pose_grid": options.pose_grid or DEFAULT_GRID}
