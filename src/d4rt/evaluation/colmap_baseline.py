"""The classical camera-pose baseline: COLMAP's incremental structure from motion, through pycolmap.

Per sequence: the frames are written as PNGs, SIFT features are extracted (one shared camera,
SIMPLE_RADIAL, focal length unknown), matched exhaustively (sequentially with 10 neighbours beyond
``EXHAUSTIVE_MAX_FRAMES`` frames), and the incremental mapper reconstructs. The largest model gives the
poses; frames it did not register are reported as such, and pose metrics use the registered frames only.
Nothing is known to COLMAP but the pixels: no intrinsics, no depth. Runs on the CPU with a fixed seed;
COLMAP's multi-threaded feature stages still make runs differ slightly (seen: the same frames register,
poses move within the reconstruction's noise).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from d4rt.errors import UserError
from d4rt.evaluation.predictions import Prediction
from d4rt.evaluation.sequence import EvalSequence
from d4rt.geometry.transforms import invert_rigid

EXHAUSTIVE_MAX_FRAMES = 60


class ColmapPredictor:
    """Camera poses from pycolmap's incremental SfM (module docstring)."""

    name = "colmap"

    def __init__(self, seed: int = 0):
        try:
            import pycolmap  # noqa: F401
        except ImportError:
            raise UserError("the colmap baseline needs pycolmap: pip install 'd4rt[eval]'") from None
        self.seed = seed

    def predict(self, sequence: EvalSequence, tasks: set[str]) -> Prediction:
        if "pose" not in tasks:
            return Prediction(notes=["colmap predicts camera poses only"])
        c2w, registered, notes = self.reconstruct(sequence.rgb)
        return Prediction(cam_to_world=c2w, registered=registered, notes=notes)

    def reconstruct(self, rgb: np.ndarray, intrinsics: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """frames (T, H, W, 3) uint8 -> (camera-to-world (T, 4, 4) with identity where unregistered,
        registered (T,) bool, notes). intrinsics: a known (3, 3) camera (pixels, OpenCV centres) shared by
        every frame, held fixed (PINHOLE, no refinement), instead of a SIMPLE_RADIAL camera to estimate."""
        import pycolmap

        t = len(rgb)
        with tempfile.TemporaryDirectory(prefix="d4rt-colmap-") as tmp:
            tmp = Path(tmp)
            images, database, output = tmp / "images", tmp / "database.db", tmp / "sparse"
            images.mkdir()
            output.mkdir()
            names = [f"{i:06d}.png" for i in range(t)]
            for name, frame in zip(names, rgb):
                Image.fromarray(frame).save(images / name)
            pycolmap.logging.minloglevel = 2  # errors only: the progress bar is the report, not COLMAP's log
            pycolmap.set_random_seed(self.seed)
            extraction = pycolmap.FeatureExtractionOptions()
            extraction.use_gpu = False
            reader = pycolmap.ImageReaderOptions()
            options = pycolmap.IncrementalPipelineOptions()
            if intrinsics is not None:  # COLMAP's pixel centres are at +0.5
                k = np.asarray(intrinsics, dtype=np.float64)
                reader.camera_model = "PINHOLE"
                reader.camera_params = f"{k[0, 0]},{k[1, 1]},{k[0, 2] + 0.5},{k[1, 2] + 0.5}"
                options.ba_refine_focal_length = options.ba_refine_principal_point = False
                options.ba_refine_extra_params = False
            pycolmap.extract_features(database, images, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                      reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
            if t <= EXHAUSTIVE_MAX_FRAMES:
                pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
            else:
                pycolmap.match_sequential(database, device=pycolmap.Device.cpu)
            options.random_seed = self.seed
            options.num_threads = 1
            models = pycolmap.incremental_mapping(database, images, output, options)
        c2w = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
        registered = np.zeros(t, dtype=bool)
        if not models:
            return c2w, registered, [f"colmap registered no frame of {t} (no initial pair found)"]
        model = max(models.values(), key=lambda m: m.num_reg_images())
        index = {name: i for i, name in enumerate(names)}
        for image in model.images.values():
            if image.has_pose:
                i = index[image.name]
                c2w[i] = invert_rigid(np.vstack([image.cam_from_world().matrix(), [0.0, 0.0, 0.0, 1.0]]))
                registered[i] = True
        notes = [] if registered.all() else [f"colmap registered {int(registered.sum())} of {t} frames"
                                             + (f" (in {len(models)} separate models; the largest is used)"
                                                if len(models) > 1 else "")]
        return c2w, registered, notes
