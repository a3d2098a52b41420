"""A view of a clip: an integer-pixel crop of every frame, resized to an output size, on a subset of
frames. Crops, zoom-ins and temporal strides of the data augmentation are all views, and a view maps
intrinsics, (u, v) and frame indices exactly, so ground truth stays exact through augmentation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from d4rt.errors import UserError


@dataclass(frozen=True)
class View:
    """Crop ``(x0, y0, w, h)`` (whole source pixels) of frames ``frames`` of a ``source_size`` clip,
    resized to ``size``; all sizes are (height, width).

    Normalised coordinates map as ``u_src = (x0 + u * w) / W_src`` (and likewise v), which is exactly
    what bilinear resizing with ``align_corners=False`` does to pixel centres.
    """

    source_size: tuple[int, int]
    crop: tuple[int, int, int, int]
    size: tuple[int, int]
    frames: tuple[int, ...]

    def __post_init__(self) -> None:
        hs, ws = self.source_size
        x0, y0, w, h = self.crop
        if not (0 <= x0 and 0 <= y0 and w > 0 and h > 0 and x0 + w <= ws and y0 + h <= hs):
            raise UserError(f"crop {self.crop} (x0, y0, w, h) does not lie inside the {ws}x{hs} frame")
        if self.size[0] <= 0 or self.size[1] <= 0:
            raise UserError(f"view size {self.size} must be positive (height, width)")
        if len(self.frames) == 0:
            raise UserError("a view needs at least one frame")

    @classmethod
    def full(cls, num_frames: int, height: int, width: int) -> "View":
        """The identity view of a (num_frames, height, width) clip."""
        return cls((height, width), (0, 0, width, height), (height, width), tuple(range(num_frames)))

    def check_frames(self, num_frames: int) -> None:
        """Raise if the view names frames the source clip does not have."""
        bad = [f for f in self.frames if not 0 <= f < num_frames]
        if bad:
            raise UserError(f"view frames {bad} are outside the clip's {num_frames} frames")

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    def _affine(self) -> tuple[float, float, float, float]:
        """Pixel map x_view = sx * x_src + bx, y_view = sy * y_src + by (OpenCV pixel centres)."""
        hs, ws = self.source_size
        x0, y0, w, h = self.crop
        ho, wo = self.size
        sx, sy = wo / w, ho / h
        # x_view + 0.5 = (x_src + 0.5 - x0) * sx
        return sx, sy, (0.5 - x0) * sx - 0.5, (0.5 - y0) * sy - 0.5

    def intrinsics(self, source_intrinsics: np.ndarray) -> np.ndarray:
        """Intrinsics of the view's frames. source_intrinsics: (T_src, 3, 3) -> (T_view, 3, 3)."""
        sx, sy, bx, by = self._affine()
        a = np.array([[sx, 0.0, bx], [0.0, sy, by], [0.0, 0.0, 1.0]])
        return a @ np.asarray(source_intrinsics, dtype=np.float64)[list(self.frames)]

    def uv_to_source(self, uv):
        """View (u, v) -> source (u, v). uv: (..., 2) numpy or torch."""
        hs, ws = self.source_size
        x0, y0, w, h = self.crop
        u = (x0 + uv[..., 0] * w) / ws
        v = (y0 + uv[..., 1] * h) / hs
        return _stack([u, v], uv)

    def uv_from_source(self, uv):
        """Source (u, v) -> view (u, v) (may fall outside [0, 1] when outside the crop)."""
        hs, ws = self.source_size
        x0, y0, w, h = self.crop
        u = (uv[..., 0] * ws - x0) / w
        v = (uv[..., 1] * hs - y0) / h
        return _stack([u, v], uv)

    def time_to_source(self, t):
        """View frame indices (float or int tensor/array holding integers) -> source frame indices."""
        lut = self.frames
        if isinstance(t, torch.Tensor):
            table = torch.tensor(lut, dtype=torch.long, device=t.device)
            return table[t.long()].to(t.dtype)
        return np.asarray(lut)[np.asarray(t).astype(np.int64)].astype(np.asarray(t).dtype)


def _stack(parts, like):
    if isinstance(like, torch.Tensor):
        return torch.stack(parts, -1)
    return np.stack(parts, -1)
