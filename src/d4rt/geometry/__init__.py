"""Pure geometric functions (camera model, rigid transforms, image-plane views); no I/O, no learning."""

from d4rt.geometry.camera import cell_centres_uv, pixel_grid, pixel_to_uv, project, unproject_depth, uv_to_pixel
from d4rt.geometry.transforms import apply_transform, invert_rigid, rotation_about_axis
from d4rt.geometry.umeyama import Similarity, umeyama
from d4rt.geometry.view import View

__all__ = [
    "Similarity",
    "View",
    "apply_transform",
    "cell_centres_uv",
    "invert_rigid",
    "pixel_grid",
    "pixel_to_uv",
    "project",
    "rotation_about_axis",
    "umeyama",
    "unproject_depth",
    "uv_to_pixel",
]
