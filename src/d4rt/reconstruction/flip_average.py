"""Test-time flip averaging: each query answered on the video and on its left-right mirror, the two averaged.

Not in paper. A left-right mirror of a video is as likely a video as the video itself, so a model answers the
mirrored clip as well as the clip, with errors that are not the same: the mean of the two answers (the mirrored
one mirrored back) has less of the error that is not shared. It is the flip post-processing of monocular depth
networks, applied to every output of a query. It costs two encoder passes and twice the queries.

The mirror in this package's conventions (OpenCV camera, (u, v) over the image with pixel centres at
(i + 0.5) / W): pixel column i becomes W - 1 - i, so u becomes 1 - u exactly and v is unchanged; in camera
coordinates x becomes -x (a mirror of the image is a mirror of the camera's x axis), so points, motion and
normals negate their x, while visibility and confidence do not change.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

# Every answer of a query (``EncodedScene.query``; written out here: the recipes never import the model).
ANSWER_KEYS = ("points", "uv", "visibility", "motion", "normals", "confidence")
# Answers whose first coordinate is a camera-space x (negated by the mirror).
CAMERA_VECTORS = ("points", "motion", "normals")


def mirror_video(video: Any) -> Any:
    """``video (T, H, W, 3)``, numpy or torch, mirrored left-right (a contiguous copy)."""
    if torch.is_tensor(video):
        return video.flip(2)
    return np.ascontiguousarray(np.asarray(video)[:, :, ::-1])


def mirror_queries(queries: Any) -> Any:
    """``queries (N, 5)`` = [u, v, t_src, t_tgt, t_cam] of a video, as the same pixels of its mirror (u -> 1 - u)."""
    mirrored = queries.clone() if torch.is_tensor(queries) else np.array(queries, dtype=np.float64, copy=True)
    mirrored[:, 0] = 1 - mirrored[:, 0]
    return mirrored


def mirror_answers(answers: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Answers about a mirrored video, as answers about the video itself (x -> -x, u -> 1 - u)."""
    out = dict(answers)
    for key in CAMERA_VECTORS:
        out[key] = answers[key] * answers[key].new_tensor([-1.0, 1.0, 1.0])
    out["uv"] = torch.stack([1 - answers["uv"][:, 0], answers["uv"][:, 1]], -1)
    return out


def average_answers(first: dict[str, torch.Tensor], second: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The mean of two answers to the same queries; normals renormalised to unit length."""
    mean = {key: (first[key] + second[key]) / 2 for key in ANSWER_KEYS}
    norm = mean["normals"].norm(dim=-1, keepdim=True)
    # Two opposite normals average to nothing: keep the first answer's there rather than divide by zero.
    mean["normals"] = torch.where(norm > 1e-6, mean["normals"] / norm.clamp_min(1e-6), first["normals"])
    return mean


class FlipAveraged:
    """An answerer of a video made of two: ``plain`` (the video encoded) and ``mirrored`` (its mirror encoded).
    ``query`` takes what ``EncodedScene.query`` takes and returns the same keys and shapes (module docstring)."""

    def __init__(self, plain, mirrored):
        if plain.num_frames != mirrored.num_frames:
            raise ValueError("the plain and mirrored answerers cover different numbers of frames")
        self.plain, self.mirrored = plain, mirrored
        self.num_frames = plain.num_frames
        self.parts = (plain, mirrored)  # what the window cache counts (sources.encoded_bytes)

    def query(self, queries, **options) -> dict[str, torch.Tensor]:
        plain = self.plain.query(queries, **options)  # checks the queries first
        mirrored = mirror_answers(self.mirrored.query(mirror_queries(queries), **options))
        return average_answers(plain, mirrored)


def flip_averaged(encode: Callable[[Any], Any]) -> Callable[[Any], FlipAveraged]:
    """``encode`` (video -> answerer, such as ``model.encode``) made flip-averaged."""

    def encode_both(video):
        return FlipAveraged(encode(video), encode(mirror_video(video)))

    return encode_both
