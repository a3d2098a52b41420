"""A binary glTF (GLB) scene of the point cloud and the camera frusta, through trimesh (opens in Blender,
three.js viewers, and most 3D tools).

glTF is y-up with cameras looking down -z, while d4rt's world is the OpenCV camera 0 (y down, z
forward): the scene is rotated 180 degrees about x, so (x, y, z) is written as (x, -y, -z) and the
first camera looks down -z with up +y, the way glTF viewers expect.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

OPENCV_TO_GLTF = np.diag([1.0, -1.0, -1.0, 1.0])
FRUSTUM_COLOR = np.array([255, 96, 32, 255], dtype=np.uint8)


def write_glb(path: str | Path, points: np.ndarray, colors: np.ndarray, frusta: np.ndarray) -> Path:
    """points: (M, 3) world (OpenCV camera 0); colors: (M, 3) uint8; frusta: (T, K, 2, 3) world segments
    (see ``d4rt.viz.frusta``). Writes nodes ``points`` and ``cameras``."""
    import trimesh  # here: importing it takes 0.5 s, and most commands never write a GLB

    scene = trimesh.Scene()
    if len(points):
        rgba = np.concatenate([colors, np.full((len(colors), 1), 255, np.uint8)], 1)
        scene.add_geometry(trimesh.PointCloud(points, colors=rgba), node_name="points", geom_name="points")
    segments = frusta.reshape(-1, 2, 3)
    if len(segments):
        lines = trimesh.load_path(segments)
        lines.colors = np.tile(FRUSTUM_COLOR, (len(lines.entities), 1))
        scene.add_geometry(lines, node_name="cameras", geom_name="cameras")
    scene.apply_transform(OPENCV_TO_GLTF)
    path = Path(path)
    path.write_bytes(scene.export(file_type="glb"))
    return path
