"""d4rt: D4RT in PyTorch.

One video encoder builds a Global Scene Representation once; independent queries
(u, v, t_src, t_tgt, t_cam) decode depth, 3D tracks, point clouds and cameras from it.
Conventions (OpenCV camera, camera-to-world poses, pixel intrinsics, (u, v) in [0, 1]) are in README.md.
"""

__version__ = "0.1.0"
