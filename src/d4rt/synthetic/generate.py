"""``render_clip``: draw a random scene from a seed and render it with full ground truth."""

from __future__ import annotations

from d4rt.errors import UserError
from d4rt.synthetic.clip import Clip
from d4rt.synthetic.render import render
from d4rt.synthetic.sampling import SceneOptions, sample_scene


def render_clip(seed: int, frames: int, height: int, width: int, *, device="cpu", aa_samples: int = 2,
                **scene_options) -> Clip:
    """Render a random dynamic scene: the same arguments give the same clip, bit for bit (same device).

    seed: non-negative int. frames, height, width: clip size (any aspect ratio). device: where to
    ray-cast ("cpu", "cuda", ...). aa_samples: n for the n x n supersampling of edge pixels (1 = off).
    scene_options: fields of ``SceneOptions`` (environment, num_objects, camera_motion, shake,
    fov_degrees, zoom, articulated, moving_fraction, fps, time_stride, principal_point_jitter, shadows).
    """
    unknown = sorted(set(scene_options) - set(SceneOptions.__dataclass_fields__))
    if unknown:
        raise UserError(f"unknown scene options {unknown}; known: {sorted(SceneOptions.__dataclass_fields__)}")
    if aa_samples < 1:
        raise UserError(f"aa_samples must be >= 1, got {aa_samples}")
    sampled = sample_scene(seed, frames, height, width, SceneOptions(**scene_options))
    out = render(sampled.description, sampled.intrinsics, sampled.cam_to_world, sampled.object_to_world,
                 height, width, device=device, aa_samples=aa_samples)
    return Clip(out["rgb"], out["depth"], out["normals"], out["object_ids"], sampled.intrinsics,
                sampled.cam_to_world, sampled.object_to_world, sampled.description)
