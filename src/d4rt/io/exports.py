"""Writing a reconstruction to files people can open: numpy arrays, depth PNGs and video, PLY, GLB, a
COLMAP model, a TUM trajectory, a track-overlay video, a rerun recording and an offline HTML viewer.

The queries run once (:func:`d4rt.io.output_plan.compute_outputs`, only what the chosen formats need),
then each format is written from the same arrays (:func:`d4rt.io.writers.write_outputs`), atomically
(:mod:`d4rt.io.staging`). Units and conventions of every file: ``docs/outputs.md``.
"""

from __future__ import annotations

import tempfile
from contextlib import contextmanager
from pathlib import Path

from d4rt.io.formats import check_output_dir, parse_formats
from d4rt.io.output_plan import compute_outputs
from d4rt.io.writers import write_outputs


def export_reconstruction(rec, directory: str | Path, formats="all", *, overwrite: bool = False,
                          progress: bool = False, **options) -> list[Path]:
    """Decode and write the chosen formats of a :class:`d4rt.reconstruction.Reconstruction` (names in
    ``d4rt.io.formats.FORMATS``, "all", or a comma-separated string) into ``directory`` (new or empty;
    ``overwrite``: its old contents are replaced as a whole, atomically); ``options`` (resolution,
    intrinsics, camera, square_pixels, min_confidence, point_stride, points_from, track_grid, track_frame,
    dense_resolution, max_points, motion_resolution, motion_threshold, known_poses, scale, timestamps, fps) go
    to :func:`compute_outputs`. Returns the paths written."""
    names = parse_formats(formats)
    directory = check_output_dir(directory, overwrite)
    with spool_folder(directory) as spool:  # the arrays that grow with the video wait on disk, not in memory
        outputs = compute_outputs(rec, names, progress=progress, spool=spool, **options)
        return write_outputs(outputs, directory, names, overwrite=overwrite, progress=progress)


@contextmanager
def spool_folder(directory: str | Path):
    """A hidden temporary folder beside ``directory`` (where the outputs' disk space is; the system's
    temporary folder may be a RAM disk), removed afterwards, for arrays too large to hold in memory."""
    parent = Path(directory).absolute().parent
    with tempfile.TemporaryDirectory(prefix=f".{Path(directory).name}.spool-",
                                     dir=parent if parent.is_dir() else None) as spool:
        yield Path(spool)
