"""Baselines run through the same harness as D4RT, so every table has a reference beside the model.

- ``oracle``: the ground truth itself (sanity check: must score perfectly). On synthetic sequences it
  goes through the same query recipes as the model, answered by the clip's exact oracle, so it also
  checks the recipes and the harness end to end; elsewhere it returns the ground-truth arrays.
- ``constant-depth``: the same depth at every pixel of every frame (1.0; after per-sequence scale
  alignment it is the best single depth for the sequence). The floor any depth method must beat.
- ``static-camera``: every frame's camera at the first one's pose (identity camera-to-world). After the
  Sim(3) alignment of the pose metrics its ATE is the spread of the true camera centres about their mean:
  the floor any pose method must beat (a model that ignores camera motion scores about this).
- ``constant-velocity``: the camera walks a straight line at constant speed and never turns (camera i at
  (0, 0, i), identity rotation). The Sim(3) alignment picks the line's direction, speed and start, so its ATE
  is the RMS residual of the best straight-line-in-time fit of the true camera centres: on smooth paths far
  below ``static-camera``'s, and the floor a pose method's ATE has to beat to show it read any motion from the
  pixels. Its RPE-rot is the true frame-to-frame rotation, as ``static-camera``'s.
- ``colmap``: COLMAP incremental SfM through pycolmap, camera poses only (``d4rt.evaluation.colmap_baseline``).
"""

from __future__ import annotations

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.predictions import Prediction, Predictor, ReconstructionPredictor
from d4rt.evaluation.sequence import EvalSequence
from d4rt.reconstruction import Reconstruction

BASELINES = ("oracle", "constant-depth", "static-camera", "constant-velocity", "colmap")


class OraclePredictor:
    """Ground truth as a prediction (see the module docstring)."""

    name = "oracle"

    def __init__(self):
        self._recipes = ReconstructionPredictor(self.name, lambda sequence: Reconstruction.from_clip(sequence.clip))

    def predict(self, sequence: EvalSequence, tasks: set[str]) -> Prediction:
        if sequence.clip is not None:
            return self._recipes.predict(sequence, tasks)
        tracks = sequence.tracks
        return Prediction(depth=sequence.depth, cam_to_world=sequence.cam_to_world,
                          tracks=None if tracks is None else tracks.points,
                          track_visible=None if tracks is None else tracks.visible,
                          world_tracks=sequence.world_tracks(), point_map=sequence.point_map())


class ConstantDepthPredictor:
    """Depth 1.0 everywhere; predicts nothing else."""

    name = "constant-depth"

    def predict(self, sequence: EvalSequence, tasks: set[str]) -> Prediction:
        return Prediction(depth=np.ones((sequence.num_frames, *sequence.image_size), dtype=np.float32))


class StaticCameraPredictor:
    """Identity camera-to-world for every frame; predicts nothing else."""

    name = "static-camera"

    def predict(self, sequence: EvalSequence, tasks: set[str]) -> Prediction:
        return Prediction(cam_to_world=np.broadcast_to(np.eye(4), (sequence.num_frames, 4, 4)).copy())


def constant_velocity_poses(num_frames: int) -> np.ndarray:
    """Camera i at (0, 0, i) looking along +z: (num_frames, 4, 4) camera-to-world."""
    cam_to_world = np.tile(np.eye(4), (num_frames, 1, 1))
    cam_to_world[:, 2, 3] = np.arange(num_frames)
    return cam_to_world


class ConstantVelocityPredictor:
    """A straight line walked at constant speed (``constant_velocity_poses``); predicts nothing else."""

    name = "constant-velocity"

    def predict(self, sequence: EvalSequence, tasks: set[str]) -> Prediction:
        return Prediction(cam_to_world=constant_velocity_poses(sequence.num_frames))


def make_baseline(name: str) -> Predictor:
    if name == "oracle":
        return OraclePredictor()
    if name == "constant-depth":
        return ConstantDepthPredictor()
    if name == "static-camera":
        return StaticCameraPredictor()
    if name == "constant-velocity":
        return ConstantVelocityPredictor()
    if name == "colmap":
        from d4rt.evaluation.colmap_baseline import ColmapPredictor

        return ColmapPredictor()
    raise UserError(f"unknown baseline {name!r}; known: {list(BASELINES)}")
