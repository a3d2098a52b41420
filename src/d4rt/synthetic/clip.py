"""A clip: frames plus their complete ground truth, with an oracle, saved as one compressed npz.

npz layout (also the "bring your own data" format: any dataset that provides these arrays gets an
exact-at-pixel-centres oracle):
- ``rgb (T,H,W,3) uint8``
- ``depth (T,H,W) float32``: z-depth in the camera frame (metres); 0 or non-finite = no ground truth
- ``normals (T,H,W,3) float32``: unit surface normals in the camera frame, facing the camera
- ``object_ids (T,H,W) uint8``: rigid body per pixel, 0 = static environment
- ``intrinsics (T,3,3) float64``: pixels, OpenCV pixel centres (see README "Conventions")
- ``cam_to_world (T,4,4) float64``: OpenCV camera axes
- ``object_to_world (T,K,4,4) float64``: pose of every rigid body k (k = 0: the environment)
- optional ``scene``: the scene description as JSON (synthetic clips), which makes the oracle exact
  for any continuous (u, v) by ray casting.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from d4rt.errors import UserError
from d4rt.geometry.view import View
from d4rt.synthetic.oracle import AnalyticOracle, ArrayOracle, Oracle, ViewOracle
from d4rt.synthetic.scene import SceneDescription

FORMAT_VERSION = 1
ARRAY_DTYPES = {
    "rgb": np.uint8,
    "depth": np.float32,
    "normals": np.float32,
    "object_ids": np.uint8,
    "intrinsics": np.float64,
    "cam_to_world": np.float64,
    "object_to_world": np.float64,
}


@dataclass(eq=False)
class Clip:
    """Frames and ground truth of one clip; every array attribute is a numpy array (layout above).

    ``oracle`` answers queries exactly (``AnalyticOracle`` when ``scene`` is known, else
    ``ArrayOracle``); ``view`` / ``crop`` / ``resize`` / ``subsample`` derive clips whose intrinsics,
    frame indices and oracle stay exact.
    """

    rgb: np.ndarray
    depth: np.ndarray
    normals: np.ndarray
    object_ids: np.ndarray
    intrinsics: np.ndarray
    cam_to_world: np.ndarray
    object_to_world: np.ndarray
    scene: SceneDescription | None = None
    _oracle: Oracle | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        for name, dtype in ARRAY_DTYPES.items():
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=dtype))
        _check_shapes(self)

    @property
    def num_frames(self) -> int:
        return self.rgb.shape[0]

    @property
    def height(self) -> int:
        return self.rgb.shape[1]

    @property
    def width(self) -> int:
        return self.rgb.shape[2]

    @property
    def num_bodies(self) -> int:
        return self.object_to_world.shape[1]

    @property
    def oracle(self) -> Oracle:
        """Ground-truth answers to (N, 5) queries [u, v, t_src, t_tgt, t_cam] (see synthetic.oracle)."""
        if self._oracle is None:
            if self.scene is not None:
                self._oracle = AnalyticOracle(self.scene, self.intrinsics, self.cam_to_world, self.object_to_world,
                                              self.height, self.width)
            else:
                self._oracle = ArrayOracle(self.depth, self.normals, self.object_ids, self.intrinsics,
                                           self.cam_to_world, self.object_to_world)
        return self._oracle

    def reconstruction(self, *, window: int | None = None, overlap: int | None = None, **options):
        """The query recipes over this clip's exact oracle: ``Reconstruction.from_clip(self, ...)``
        (:class:`d4rt.reconstruction.Reconstruction`): depth, cameras, tracks and point clouds are ground
        truth (``window`` splits the clip into overlapping windows, to test long-video stitching exactly)."""
        # A shortcut kept because outside code relies on it (issue 4's fixed interface); the one upward
        # reference of this layer, resolved at call time and allowed by name in docs/architecture.md.
        from d4rt.reconstruction import Reconstruction

        return Reconstruction.from_clip(self, window=window, overlap=overlap, **options)

    # ---------------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write the clip as one compressed npz (atomically: write then rename)."""
        path = Path(path)
        if path.suffix != ".npz":
            raise UserError(f"clip files must end in .npz, got {path}")
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {name: getattr(self, name) for name in ARRAY_DTYPES}
        arrays["format_version"] = np.array(FORMAT_VERSION)
        if self.scene is not None:
            arrays["scene"] = np.array(self.scene.to_json())
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
        return path

    def view(self, view: View) -> "Clip":
        """The clip seen through ``view`` (crop, resize, frame subset); ground truth stays exact.

        RGB is cropped and resized (bilinear, anti-aliased). Synthetic clips re-render their geometry
        buffers for the new pixel grid, so depth, normals and ids stay exact everywhere. Clips without a
        scene description crop them exactly; when resized, the buffers are nearest-pixel resampled and
        the oracle keeps answering from the original pixels through the view (exact at their centres).
        """
        if view.source_size != (self.height, self.width):
            raise UserError(f"view is for {view.source_size} frames, this clip is {(self.height, self.width)}")
        view.check_frames(self.num_frames)
        frames = list(view.frames)
        x0, y0, w, h = view.crop
        rgb = view_rgb(self.rgb, view)
        intrinsics = view.intrinsics(self.intrinsics)
        c2w, o2w = self.cam_to_world[frames], self.object_to_world[frames]
        resized = view.size != (h, w)
        if self.scene is not None:
            from d4rt.synthetic.render import render  # local: render imports this module's siblings

            geo = render(self.scene, intrinsics, c2w, o2w, *view.size, geometry_only=True)
            return Clip(rgb, geo["depth"], geo["normals"], geo["object_ids"], intrinsics, c2w, o2w, self.scene)
        crop = (slice(None), slice(y0, y0 + h), slice(x0, x0 + w))
        depth, normals, ids = (a[frames][crop] for a in (self.depth, self.normals, self.object_ids))
        if not resized:
            return Clip(rgb, depth, normals, ids, intrinsics, c2w, o2w)
        depth, normals, ids = (_resize_nearest(a, view.size) for a in (depth, normals, ids))
        return Clip(rgb, depth, normals, ids, intrinsics, c2w, o2w, _oracle=ViewOracle(self.oracle, view))

    def crop(self, x0: int, y0: int, width: int, height: int) -> "Clip":
        """Crop every frame to the pixel box (x0, y0, width, height)."""
        return self.view(View((self.height, self.width), (x0, y0, width, height), (height, width),
                              tuple(range(self.num_frames))))

    def resize(self, height: int, width: int) -> "Clip":
        """Resize every frame to (height, width)."""
        return self.view(View((self.height, self.width), (0, 0, self.width, self.height), (height, width),
                              tuple(range(self.num_frames))))

    def subsample(self, frames) -> "Clip":
        """Keep the given frame indices (e.g. ``range(0, T, 2)`` for a temporal stride of 2)."""
        return self.view(View((self.height, self.width), (0, 0, self.width, self.height),
                              (self.height, self.width), tuple(int(f) for f in frames)))


def load_clip(path: str | os.PathLike) -> Clip:
    """Read a clip written by ``Clip.save`` / ``d4rt generate`` (or any npz in the same layout)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"clip file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in ARRAY_DTYPES if k not in data.files]
            if missing:
                raise UserError(f"{path} is not a d4rt clip: missing arrays {missing}")
            arrays = {k: data[k] for k in ARRAY_DTYPES}
            scene = SceneDescription.from_json(str(data["scene"])) if "scene" in data.files else None
    except UserError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, json.JSONDecodeError, TypeError, KeyError) as err:
        raise UserError(f"cannot read clip {path}: {type(err).__name__}: {err}") from None
    return Clip(**arrays, scene=scene)


def _check_shapes(clip: Clip) -> None:
    t, h, w = clip.rgb.shape[:3] if clip.rgb.ndim == 4 else (None, None, None)
    expect = {
        "rgb": (t, h, w, 3),
        "depth": (t, h, w),
        "normals": (t, h, w, 3),
        "object_ids": (t, h, w),
        "intrinsics": (t, 3, 3),
        "cam_to_world": (t, 4, 4),
    }
    if t is None or clip.rgb.shape[3] != 3:
        raise UserError(f"rgb must have shape (T, H, W, 3), got {clip.rgb.shape}")
    for name, shape in expect.items():
        if getattr(clip, name).shape != shape:
            raise UserError(f"{name} has shape {getattr(clip, name).shape}, expected {shape}")
    o2w = clip.object_to_world
    if o2w.ndim != 4 or o2w.shape[0] != t or o2w.shape[2:] != (4, 4):
        raise UserError(f"object_to_world has shape {o2w.shape}, expected ({t}, K, 4, 4)")
    if clip.scene is not None and clip.scene.num_bodies != o2w.shape[1]:
        raise UserError(f"scene describes {clip.scene.num_bodies} bodies but object_to_world has {o2w.shape[1]}")


def view_rgb(rgb: np.ndarray, view: View) -> np.ndarray:
    """The frames of ``view``: (T, H, W, 3) uint8 -> (T_view, h, w, 3) uint8, cropped and resized."""
    x0, y0, w, h = view.crop
    return _resize_rgb(rgb[list(view.frames), y0:y0 + h, x0:x0 + w], view.size)


def view_depth(depth: np.ndarray, view: View) -> np.ndarray:
    """The depth maps of ``view``: (T, H, W) float32 -> (T_view, h, w) float32, cropped, and resized by taking
    the source pixel nearest to each output pixel centre (depths are never blended across an edge); 0 where
    the source has no ground truth (0 or non-finite)."""
    x0, y0, w, h = view.crop
    depth = _resize_nearest(depth[list(view.frames), y0:y0 + h, x0:x0 + w], view.size).astype(np.float32)
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(0.0))


def _resize_rgb(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(T, h, w, 3) uint8 -> (T, H, W, 3) uint8, bilinear with anti-aliasing (pixel centres aligned)."""
    if rgb.shape[1:3] == tuple(size):
        return np.ascontiguousarray(rgb)
    x = torch.from_numpy(np.ascontiguousarray(rgb)).permute(0, 3, 1, 2).float()
    y = F.interpolate(x, size=size, mode="bilinear", align_corners=False, antialias=True)
    return y.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()


def _resize_nearest(a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(T, h, w[, C]) -> (T, H, W[, C]) taking the source pixel nearest to each output pixel centre."""
    h, w = a.shape[1:3]
    rows = np.minimum(((np.arange(size[0]) + 0.5) * h / size[0]).astype(np.int64), h - 1)
    cols = np.minimum(((np.arange(size[1]) + 0.5) * w / size[1]).astype(np.int64), w - 1)
    return np.ascontiguousarray(a[:, rows][:, :, cols])
