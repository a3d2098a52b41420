"""The names, defaults and argument checks of the export formats, with no heavy imports, so the command
line can build its help and refuse bad arguments before torch loads."""

from __future__ import annotations

import sys
from pathlib import Path

from d4rt.errors import UserError
from d4rt.viz.rerun_recording import rerun_available

# Format name -> what it writes (in OUT_DIR), in the order they are written.
FORMATS = {
    "npz": "reconstruction.npz",
    "depth": "depth/000000.png ... (16-bit) + depth/depth_scale.json",
    "depth-video": "depth.mp4",
    "ply": "points.ply",
    "glb": "scene.glb",
    "colmap": "colmap/images/, colmap/sparse/0/",
    "tum": "trajectory_tum.txt",
    "tracks-video": "tracks.mp4",
    "rerun": "reconstruction.rrd",
    "html": "viewer.html",
    "dense-tracks": "dense_tracks.npz",
    "motion-masks": "motion/000000.png ... (8-bit, 255 = moving) + motion/motion.npz",
}
# Asked for by name only ("all" leaves them out): dense tracking decodes millions of queries, moving-object masks
# several queries per pixel.
ON_REQUEST = ("dense-tracks", "motion-masks")
# What each format needs decoded.
FORMAT_NEEDS = {
    "npz": {"depth", "cameras", "points", "tracks"},
    "depth": {"depth"},
    "depth-video": {"depth"},
    "ply": {"points"},
    "glb": {"points", "cameras"},
    "colmap": {"points", "cameras", "colmap-points"},
    "tum": {"cameras"},
    "tracks-video": {"tracks", "cameras"},
    "rerun": {"depth", "cameras", "points", "tracks"},
    "html": {"points", "cameras", "tracks"},
    "dense-tracks": {"dense", "cameras"},
    "motion-masks": {"motion"},
}
DEFAULT_FPS = 10.0  # for the videos and the viewer when the input has no clock
# Points of the COLMAP model: each costs COLMAP_VIEWS queries, so this bounds both the file and the cost
# (20,000 x 8 = 160k queries, a fifth of a 48-frame 128x128 video's depth maps); --max-points raises it.
DEFAULT_MAX_POINTS = 20_000
# Frames each COLMAP point is queried in (its source frame among them), spread over its window: plenty for
# bundle adjustment and splatting, at a sixth of the queries of tracking it through 48 frames.
COLMAP_VIEWS = 8
# "auto" camera model: one camera unless the per-frame focal lengths' 90th / 10th percentiles differ more.
CAMERA_CHOICES = ("auto", "single", "per-frame")
# Where the point cloud comes from: the decoded depth maps and cameras, or the paper's direct queries.
POINT_SOURCES = ("depth", "queries")
ZOOM_SPREAD = 1.15


def parse_formats(formats) -> list[str]:
    """"all", a comma-separated string or a list of names -> the list of format names (in FORMATS
    order). "all" is every format but those in ON_REQUEST (dense tracks). With "all", the rerun recording
    is left out (with a notice) when rerun-sdk is missing; asked for by name, it is an error."""
    if isinstance(formats, str):
        names = ([f for f in FORMATS if f not in ON_REQUEST] if formats == "all"
                 else [f.strip() for f in formats.split(",") if f.strip()])
        everything = formats == "all"
    else:
        names, everything = list(formats), False
    unknown = [n for n in names if n not in FORMATS]
    if unknown or not names:
        raise UserError(f"unknown output format(s) {unknown or names}; choose from all, {', '.join(FORMATS)}")
    if "rerun" in names and not rerun_available():
        if not everything:
            raise UserError("the rerun output needs the rerun-sdk package: pip install 'd4rt[viewer]'")
        print("d4rt: skipping reconstruction.rrd: rerun-sdk is not installed (pip install 'd4rt[viewer]')",
              file=sys.stderr)
        names.remove("rerun")
    return [n for n in FORMATS if n in names]


def check_output_dir(directory: str | Path, overwrite: bool = False) -> Path:
    """The output folder, checked before any work: it must not exist, be empty, or (``overwrite``) be a
    folder whose whole contents the new run may replace. Mixing one run's files with another's would
    leave stale outputs beside fresh ones."""
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise UserError(f"output {directory} exists and is not a directory")
    if not overwrite and directory.is_dir() and any(directory.iterdir()):
        raise UserError(f"output folder {directory} is not empty: pass --overwrite to replace it (overwrite=True "
                        "in Python), or choose another folder")
    return directory
