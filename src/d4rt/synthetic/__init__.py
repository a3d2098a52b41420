"""The synthetic dynamic-scene engine: exact ground truth for every point at every time.

- ``render_clip(seed, frames, height, width, **scene_options) -> Clip``: a random scene, rendered.
- ``load_clip(path) -> Clip``; ``clip.save(path)``.
- ``clip.oracle.query(queries)``: exact answers to (N, 5) [u, v, t_src, t_tgt, t_cam] queries.
"""

from d4rt.synthetic.clip import Clip, load_clip
from d4rt.synthetic.generate import render_clip
from d4rt.synthetic.oracle import AnalyticOracle, ArrayOracle, Oracle, ViewOracle
from d4rt.synthetic.sampling import CAMERA_MOTIONS, SceneOptions

__all__ = [
    "AnalyticOracle",
    "ArrayOracle",
    "CAMERA_MOTIONS",
    "Clip",
    "Oracle",
    "SceneOptions",
    "ViewOracle",
    "load_clip",
    "render_clip",
]
