"""d4rt: D4RT in PyTorch.

One video encoder builds a Global Scene Representation once; independent queries
(u, v, t_src, t_tgt, t_cam) decode depth, 3D tracks, point clouds and cameras from it.
Conventions (OpenCV camera, camera-to-world poses, pixel intrinsics, (u, v) in [0, 1]) are in README.md.
"""

__version__ = "0.1.0"

_LAZY = {
    "D4RT": ("d4rt.model", "D4RT"),
    "D4RTConfig": ("d4rt.config", "D4RTConfig"),
    "Reconstruction": ("d4rt.reconstruction", "Reconstruction"),
}


def __getattr__(name: str):
    # Lazy: `import d4rt` (and the CLI's start) stays fast; the heavy modules load on first use.
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    if name in ("synthetic", "geometry", "data", "model", "reconstruction", "evaluation", "training"):
        import importlib

        return importlib.import_module(f"d4rt.{name}")
    raise AttributeError(f"module 'd4rt' has no attribute {name!r}")


__all__ = ["D4RT", "D4RTConfig", "Reconstruction", "__version__"]
