"""This project's synthetic clips (``d4rt generate`` output, or any .npz in the clip layout).

Layout: ``ROOT/*.npz``, one clip each (README "Clip files"). Depth, intrinsics and poses come from the
clip; 3D tracks are drawn from the clip's exact oracle: ``num_tracks`` query pixels (pixel centres, half
of them on objects when the clip has any, the rest anywhere), each at a random query frame, tracked
through every frame in each frame's camera with the oracle's exact visibility. The draw depends only on
``track_seed``, so the same clip always gets the same tracks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.readers._files import natural_key
from d4rt.evaluation.sequence import EvalSequence, TrackAnnotations
from d4rt.synthetic.clip import Clip, load_clip

NUM_TRACKS = 256


def list_sequences(root: Path) -> list[str]:
    names = [p.stem for p in sorted(root.glob("*.npz"), key=natural_key)]
    if not names:
        raise UserError(f"no clip .npz files in {root}")
    return names


def read_sequence(root: Path, name: str, num_tracks: int = NUM_TRACKS, track_seed: int = 0) -> EvalSequence:
    return sequence_from_clip(load_clip(root / f"{name}.npz"), name, num_tracks, track_seed)


def sequence_from_clip(clip: Clip, name: str, num_tracks: int = NUM_TRACKS, track_seed: int = 0) -> EvalSequence:
    """An evaluation sequence with the clip's full ground truth and oracle tracks."""
    return EvalSequence(name, clip.rgb, clip.depth, clip.intrinsics, clip.cam_to_world,
                        tracks=oracle_tracks(clip, num_tracks, track_seed), clip=clip)


def oracle_tracks(clip: Clip, num_tracks: int, seed: int) -> TrackAnnotations:
    """Exact 3D tracks of ``num_tracks`` random query pixels, in each frame's camera (module docstring)."""
    if num_tracks < 1:
        raise UserError(f"num_tracks must be at least 1, got {num_tracks}")
    rng = np.random.default_rng(seed)
    t, h, w = clip.num_frames, clip.height, clip.width
    query_frames = rng.integers(0, t, num_tracks)
    on_objects = np.arange(num_tracks) < num_tracks // 2
    xy = np.empty((num_tracks, 2))
    for i, (frame, want_object) in enumerate(zip(query_frames, on_objects)):
        valid = clip.depth[frame] > 0
        if want_object and (valid & (clip.object_ids[frame] > 0)).any():
            valid &= clip.object_ids[frame] > 0
        rows, cols = np.nonzero(valid)
        if len(rows) == 0:
            raise UserError(f"frame {frame} of the clip has no pixel with ground-truth depth to track")
        pick = rng.integers(len(rows))
        xy[i] = cols[pick], rows[pick]
    uv = (xy + 0.5) / [w, h]
    frames = np.arange(t)
    queries = np.concatenate([np.repeat(uv, t, 0), np.repeat(query_frames, t)[:, None],
                              np.tile(frames, num_tracks)[:, None].repeat(2, 1)], 1)
    out = clip.oracle.query(queries)
    points = out["points"].numpy().reshape(num_tracks, t, 3).transpose(1, 0, 2)
    visible = out["visibility"].numpy().reshape(num_tracks, t).T > 0.5
    return TrackAnnotations(points, visible, query_frames, xy)
