"""Training on your own clips that have per-point 3D tracks instead of rigid-body poses.

Datasets such as PointOdyssey, Dynamic Replica or Kubric's point tracks give, for many surface points,
their 3D position at every frame and whether they are visible, but no pose per rigid body, so the clip
layout of :mod:`d4rt.synthetic.clip` (whose oracle moves points with their body) does not apply. A
*track clip* is one compressed ``.npz`` with:

- ``rgb (T, H, W, 3) uint8``: the frames;
- ``intrinsics (T, 3, 3)``: pixels, OpenCV pixel centres; ``cam_to_world (T, 4, 4)``: OpenCV axes;
- ``tracks (N, T, 3)``: world position of point n at frame t (NaN where unknown);
- ``visible (N, T) bool``: point n is visible (in the image and not occluded) in frame t.

Queries are drawn at the tracked points: a (point, source frame) pair where the point is visible and
inside the view's crop gives (u, v, t_src) = its projection; t_tgt and t_cam are uniform over the
view's frames, with t_cam := t_tgt with probability ``tgt_equals_cam_prob`` (the paper's sampler). The
targets follow from the tracks exactly: the point at t_tgt in camera t_cam, its projection into frame
t_tgt, its visibility there (from ``visible``, and inside the crop), and its motion from t_src to t_tgt
in camera t_cam. Tracks carry no normals, so samples have ``normals_valid`` all False and the normal
loss skips them. The same geometric augmentations (crops, zoom-in, temporal stride) and photometric
ones as :class:`d4rt.data.ClipQueryDataset` apply.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from d4rt.data.augment import AugmentConfig, augmented_view_frames, sample_view
from d4rt.errors import UserError
from d4rt.geometry.camera import project
from d4rt.geometry.transforms import apply_rotation, apply_transform, invert_rigid
from d4rt.geometry.view import View

TRACK_ARRAYS = {"rgb": np.uint8, "intrinsics": np.float64, "cam_to_world": np.float64, "tracks": np.float64,
                "visible": bool}


@dataclass(eq=False)
class TrackClip:
    """Frames, cameras and per-point tracks of one clip (layout in the module docstring)."""

    rgb: np.ndarray
    intrinsics: np.ndarray
    cam_to_world: np.ndarray
    tracks: np.ndarray
    visible: np.ndarray

    def __post_init__(self) -> None:
        for name, dtype in TRACK_ARRAYS.items():
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=dtype))
        t = self.rgb.shape[0] if self.rgb.ndim == 4 else None
        n = self.tracks.shape[0] if self.tracks.ndim == 3 else None
        expect = {"rgb": (t, *self.rgb.shape[1:3], 3), "intrinsics": (t, 3, 3), "cam_to_world": (t, 4, 4),
                  "tracks": (n, t, 3), "visible": (n, t)}
        for name, shape in expect.items():
            if None in shape or getattr(self, name).shape != shape:
                raise UserError(f"track clip {name} has shape {getattr(self, name).shape}, expected "
                                f"{tuple('?' if s is None else s for s in shape)}")

    @property
    def num_frames(self) -> int:
        return self.rgb.shape[0]

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, **{name: getattr(self, name) for name in TRACK_ARRAYS})
        return path


def load_track_clip(path: str | Path) -> TrackClip:
    """Read a track clip ``.npz`` (no pickles)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in TRACK_ARRAYS if k not in data.files]
            if missing:
                raise UserError(f"{path} is not a track clip: missing arrays {missing}")
            return TrackClip(**{k: data[k] for k in TRACK_ARRAYS})
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        if isinstance(err, UserError):
            raise
        raise UserError(f"cannot read track clip {path}: {type(err).__name__}: {err}") from None


@dataclass
class TrackDatasetConfig:
    """Track clips from ``directory`` (every ``*.npz``), cut into samples of ``frames`` frames resized to
    ``size`` (H, W) with ``num_queries`` queries each; ``augment`` as for the clip datasets."""

    directory: str = ""
    seed: int = 0
    frames: int = 16
    size: tuple[int, int] = (128, 128)
    num_queries: int = 2048
    tgt_equals_cam_prob: float = 0.4
    augment: AugmentConfig = field(default_factory=AugmentConfig)

    def validate(self) -> None:
        if not self.directory:
            raise UserError("data.tracks.directory must name a folder of track clips")
        if self.frames < 1 or min(self.size) < 1 or self.num_queries < 1:
            raise UserError("data.tracks frames, size and num_queries must be positive")
        if not 0.0 <= self.tgt_equals_cam_prob <= 1.0:
            raise UserError(f"data.tracks.tgt_equals_cam_prob must be in [0, 1], got {self.tgt_equals_cam_prob}")
        self.augment.validate()


def track_training_sample(clip: TrackClip, view: View, rng: np.random.Generator, num_queries: int,
                          tgt_equals_cam_prob: float, augment: AugmentConfig, patch_frames: bool = False) -> dict:
    """One training sample of ``clip`` seen through ``view``, with the keys of
    :func:`d4rt.data.make_training_sample` (``patch_frames`` as there) plus ``normals_valid (N,)`` (all False)."""
    frames = np.asarray(view.frames)
    height, width = clip.rgb.shape[1:3]
    k_src, c2w = clip.intrinsics[frames], clip.cam_to_world[frames]
    w2c = invert_rigid(c2w)
    # Every track in every view frame, in that frame's camera and image: (N, T_view, ...).
    world = clip.tracks[:, frames]
    cam = apply_transform(w2c[None], world)
    with np.errstate(divide="ignore", invalid="ignore"):  # unknown or behind-camera points: masked below
        xy, z = project(cam, k_src[None])
    uv_view = view.uv_from_source((xy + 0.5) / [width, height])
    inside = (uv_view >= 0).all(-1) & (uv_view <= 1).all(-1) & (z > 0)
    known = np.isfinite(world).all(-1)
    candidates = np.argwhere(clip.visible[:, frames] & inside & known)  # (point, source frame) pairs
    if len(candidates) == 0:
        raise UserError("no tracked point is visible inside the sampled view; check the track clip's "
                        "'visible' array and its cameras")

    n, t_view = num_queries, len(frames)
    point, t_src = candidates[rng.integers(0, len(candidates), n)].T
    t_tgt = rng.integers(0, t_view, n)
    t_cam = np.where(rng.uniform(size=n) < tgt_equals_cam_prob, t_tgt, rng.integers(0, t_view, n))
    at_tgt = world[point, t_tgt]
    valid = known[point, t_tgt]
    rotate_to_cam = w2c[t_cam]
    points = apply_transform(rotate_to_cam, at_tgt)
    motion = apply_rotation(rotate_to_cam, at_tgt - world[point, t_src])
    uv_valid = valid & (z[point, t_tgt] > 0)
    targets = {
        "points": points,
        "uv": uv_view[point, t_tgt],
        "visibility": (clip.visible[:, frames][point, t_tgt] & inside[point, t_tgt] & valid).astype(np.float64),
        "motion": motion,
        "normals": np.zeros((n, 3)),
    }
    x0, y0, w, h = view.crop
    video, patch_video = augmented_view_frames(clip.rgb, view, rng, augment, original=patch_frames)
    sample = {k: torch.from_numpy(np.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)).float()
              for k, v in targets.items()}
    queries = np.concatenate([np.clip(uv_view[point, t_src], 0.0, 1.0), np.stack([t_src, t_tgt, t_cam], 1)], 1)
    sample.update(
        video=video,
        queries=torch.from_numpy(queries).float(),
        valid=torch.from_numpy(valid),
        uv_valid=torch.from_numpy(uv_valid),
        normals_valid=torch.zeros(n, dtype=torch.bool),
        aspect_ratio=torch.tensor(w / h, dtype=torch.float32),
        intrinsics=torch.from_numpy(view.intrinsics(clip.intrinsics)).float(),
        cam_to_world=torch.from_numpy(c2w).float(),
    )
    if patch_video is not None:
        sample.update(patch_video=patch_video, patch_size=torch.tensor(patch_video.shape[1:3]))
    return sample


class TrackQueryDataset(torch.utils.data.Dataset):
    """Map-style dataset of training samples from track clips; deterministic per (seed, epoch, index)."""

    def __init__(self, config: TrackDatasetConfig, patch_frames: bool = False):
        config.validate()
        self.config = config
        self.patch_frames = patch_frames  # also yield original-resolution frames (track_training_sample)
        self.epoch = 0
        self.files = sorted(Path(config.directory).glob("*.npz"))
        if not self.files:
            raise UserError(f"no .npz track clips found in {config.directory}")

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, index: int) -> dict:
        cfg = self.config
        rng = np.random.default_rng([cfg.seed, self.epoch, index])
        clip = load_track_clip(self.files[index])
        if clip.num_frames < cfg.frames:
            raise UserError(f"track clip {self.files[index]} has {clip.num_frames} frames, fewer than the "
                            f"{cfg.frames} asked for")
        view = sample_view(rng, clip.num_frames, clip.rgb.shape[1:3], cfg.frames, cfg.size, cfg.augment)
        return track_training_sample(clip, view, rng, cfg.num_queries, cfg.tgt_equals_cam_prob, cfg.augment,
                                     self.patch_frames)
