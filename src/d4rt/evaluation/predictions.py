"""What a method predicts for one sequence, and the predictor that runs D4RT (or any answerer) through
the query recipes of :class:`d4rt.reconstruction.Reconstruction`.

Everything is in the conventions of the ground truth it is compared with: depth at the sequence's
resolution, camera-to-world poses, tracks in each frame's camera (``tracks``) or in the camera of frame
0 (``world_tracks``), and the clip's point cloud as a per-pixel map in the camera of frame 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from d4rt.evaluation.sequence import EvalSequence
from d4rt.reconstruction import Reconstruction


@dataclass(eq=False)
class Prediction:
    """A method's outputs for one sequence; None where the method does not predict that quantity.

    depth: (T, H, W); depth_confidence: (T, H, W), the method's confidence in it (higher: surer; None
    when it gives none). cam_to_world: (T, 4, 4). registered: (T,) bool, frames that have a pose (None: all).
    tracks: (T, N, 3) in each frame's camera; track_visible: (T, N) bool. world_tracks: (T, N, 3) in
    the camera of frame 0. point_map: (T, H, W, 3) every pixel's point at its own time, in the camera
    of frame 0 (NaN where the method gives none). notes: what went wrong or was left out, in words.
    """

    depth: np.ndarray | None = None
    depth_confidence: np.ndarray | None = None
    cam_to_world: np.ndarray | None = None
    registered: np.ndarray | None = None
    tracks: np.ndarray | None = None
    track_visible: np.ndarray | None = None
    world_tracks: np.ndarray | None = None
    point_map: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)


class Predictor(Protocol):
    """A method evaluated by the harness: a name for the tables and one prediction per sequence."""

    name: str

    def predict(self, sequence: EvalSequence, tasks: set[str]) -> Prediction: ...


class ReconstructionPredictor:
    """Predictions decoded with the query recipes from whatever ``reconstruct(sequence)`` returns (a
    :class:`~d4rt.reconstruction.Reconstruction` over a model or an oracle)."""

    def __init__(self, name: str, reconstruct: Callable[[EvalSequence], object]):
        self.name = name
        self.reconstruct = reconstruct

    def predict(self, sequence: EvalSequence, tasks: set[str]) -> Prediction:
        rec = self.reconstruct(sequence)
        out = Prediction()
        if "depth" in tasks or "point_cloud" in tasks:
            depth = rec.depth(resolution=sequence.image_size)
            out.depth, out.depth_confidence = depth.depth, depth.confidence
        if "pose" in tasks:
            out.cam_to_world = rec.cameras().cam_to_world
        if sequence.tracks is not None and ({"tracks", "world_tracks"} & tasks):
            sources = np.concatenate([sequence.tracks.query_frames[:, None], sequence.tracks.query_xy], 1)
            if "tracks" in tasks:
                camera = rec.tracks(sources, frame="camera")
                out.tracks = camera.points.transpose(1, 0, 2)
                out.track_visible = camera.visibility.T > 0.5
            if "world_tracks" in tasks:
                out.world_tracks = rec.tracks(sources, frame="world", reference_frame=0).points.transpose(1, 0, 2)
        if "point_cloud" in tasks:
            cloud = rec.point_cloud(reference_frame=0)
            out.point_map = np.full((sequence.num_frames, *sequence.image_size, 3), np.nan)
            out.point_map[cloud.frames, cloud.pixels[:, 1], cloud.pixels[:, 0]] = cloud.points
        return out


def d4rt_predictor(checkpoint: str, device: str = "cpu", pose_pairs: str | None = None,
                   flip_average: bool | None = None, window: int | None = None,
                   overlap: int | None = None) -> ReconstructionPredictor:
    """D4RT from a ``save_pretrained`` directory, reconstructing each sequence's video by queries (poses
    fitted as ``pose_pairs`` says and answers flip-averaged as ``flip_average`` says, by default as the model's
    config says; ``window`` / ``overlap``: frames per encoded window and frames shared, None = one window up to
    the model's ``max_frames``: see :class:`~d4rt.reconstruction.Reconstruction`)."""
    from d4rt.model import D4RT

    model = D4RT.from_pretrained(checkpoint, device=device)
    options = {} if pose_pairs is None else {"pose_pairs": pose_pairs}
    if flip_average is not None:
        options["flip_average"] = flip_average
    return ReconstructionPredictor("d4rt", lambda sequence: Reconstruction.from_model(
        model, sequence.rgb, window=window, overlap=overlap, **options))
