"""D4RT's camera recipe beside COLMAP, on equal terms: the same rendered clip at the same resolution for
both, each timed cold (its first run) and warm (the best of the rest), COLMAP with and without the true
intrinsics, and the accuracy of each beside its time (ATE after Sim(3) alignment against the clip's exact
poses, frames registered). A COLMAP run that does not register every frame is a failure: no speed-up is
computed from it.

D4RT's accuracy is that of the bundled model when the bench runs the preset it was trained as (tiny);
for other presets the weights are random and only the time means anything (``d4rt_ate`` is None).
"""

from __future__ import annotations


import numpy as np
import torch

from d4rt.evaluation.metrics.pose import pose_metrics
from d4rt.reconstruction.reconstruction import DEFAULT_GRID, Reconstruction
from d4rt.speed.options import BenchOptions
from d4rt.speed.timing import time_once


def comparison_clip(options: BenchOptions):
    """The bench's synthetic clip (the frames ``make_video`` gives), with its exact cameras."""
    from d4rt.synthetic import render_clip

    return render_clip(options.seed, options.frames, options.height, options.width, environment="room",
                       camera_motion="orbit", num_objects=5)


def _timed_runs(fn, repeats: int, device: torch.device) -> tuple[list[float], object]:
    """Cold: the first call's seconds; then ``repeats`` more (warm). Returns (seconds of every run, the
    last result)."""
    result = None

    def call():
        nonlocal result
        result = fn()

    return [time_once(call, device) for _ in range(1 + max(1, repeats))], result


def _ate(cam_to_world: np.ndarray, gt: np.ndarray, registered: np.ndarray) -> float | None:
    return pose_metrics(cam_to_world[registered], gt[registered])["ate"] if registered.sum() >= 3 else None


def compare_with_colmap(model, options: BenchOptions, trained: bool) -> dict:
    """D4RT (``model``; ``trained``: whether its weights mean anything) and COLMAP on the same clip.

    Returns seconds cold / warm for D4RT, COLMAP and COLMAP with known intrinsics, frames registered, ATE
    of each (None where it cannot be computed), and the warm-to-warm and cold-to-cold speed-ups, None when
    that COLMAP run failed (registered fewer than every frame)."""
    from d4rt.evaluation.colmap_baseline import ColmapPredictor  # raises a UserError naming the extra if missing

    device = torch.device(options.device)
    clip = comparison_clip(options)
    frames = len(clip.rgb)
    grid = {} if options.pose_grid is None else {"grid": options.pose_grid}
    video = torch.from_numpy(clip.rgb)

    def d4rt():
        with options.autocast():
            return Reconstruction.from_model(model, video, progress=False, **grid).cameras()

    d4rt_s, cameras = _timed_runs(d4rt, options.repeats, device)
    result = {"frames": frames, "size": [options.width, options.height], "repeats": options.repeats,
              "pose_grid": options.pose_grid or DEFAULT_GRID, "d4rt_trained_weights": trained,
              "d4rt_cold_s": d4rt_s[0], "d4rt_warm_s": min(d4rt_s[1:]),
              "d4rt_ate": pose_metrics(cameras.cam_to_world, clip.cam_to_world)["ate"] if trained else None,
              "colmap": {}}
    predictor = ColmapPredictor()
    for name, known in (("unknown_intrinsics", None), ("known_intrinsics", clip.intrinsics[0])):
        seconds, (c2w, registered, notes) = _timed_runs(lambda: predictor.reconstruct(clip.rgb, known), options.repeats,
                                                        torch.device("cpu"))
        failed = int(registered.sum()) < frames
        result["colmap"][name] = {
            "cold_s": seconds[0], "warm_s": min(seconds[1:]), "registered_frames": int(registered.sum()),
            "ate": _ate(c2w, clip.cam_to_world, registered), "failed": failed, "notes": notes,
            "speedup_warm": None if failed else min(seconds[1:]) / result["d4rt_warm_s"],
            "speedup_cold": None if failed else seconds[0] / result["d4rt_cold_s"]}
    return result


def describe(c: dict) -> list[str]:
    """Report lines for :func:`compare_with_colmap`'s result."""
    ate = "n/a (random weights)" if c["d4rt_ate"] is None else f"{c['d4rt_ate']:.4f}"
    lines = [f"camera pose vs COLMAP: the same {c['frames']} rendered frames of {c['size'][0]}x{c['size'][1]} for both, "
             f"cold = first run, warm = best of {c['repeats']} more",
             f"  {'D4RT (%dx%d grid)' % (c['pose_grid'], c['pose_grid']):<27} cold {c['d4rt_cold_s']:7.2f} s  warm "
             f"{c['d4rt_warm_s']:7.2f} s  {c['frames']}/{c['frames']} frames  ATE {ate}"]
    for name, r in c["colmap"].items():
        label = "COLMAP, " + name.replace("_", " ")
        ate = "n/a" if r["ate"] is None else f"{r['ate']:.4f}"
        verdict = (f"FAILED: registered {r['registered_frames']} of {c['frames']} frames, no speed-up" if r["failed"]
                   else f"D4RT {r['speedup_warm']:.1f}x faster warm, {r['speedup_cold']:.1f}x cold")
        lines.append(f"  {label:<27} cold {r['cold_s']:7.2f} s  warm {r['warm_s']:7.2f} s  "
                     f"{r['registered_frames']}/{c['frames']} frames  ATE {ate}: {verdict}")
    return lines
