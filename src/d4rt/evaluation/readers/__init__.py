"""Readers for the benchmark formats the D4RT paper evaluates on, each in its dataset's published
on-disk layout (documented in each module), returning :class:`~d4rt.evaluation.sequence.EvalSequence`.

Every format module offers ``list_sequences(root) -> [name]`` and ``read_sequence(root, name, ...)``;
sequences are read one at a time, so a benchmark never has to fit in memory at once.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.readers import bonn, kitti, re10k, scannet, sintel, synthetic, tapvid3d
from d4rt.evaluation.sequence import EvalSequence

FORMATS: dict[str, ModuleType] = {
    "sintel": sintel,
    "bonn": bonn,
    "kitti": kitti,
    "scannet": scannet,
    "tapvid3d": tapvid3d,
    "re10k": re10k,
    "synthetic": synthetic,
}


def reader(fmt: str) -> ModuleType:
    if fmt not in FORMATS:
        raise UserError(f"unknown dataset format {fmt!r}; known: {sorted(FORMATS)}")
    return FORMATS[fmt]


def list_sequences(fmt: str, root: str | Path) -> list[str]:
    return reader(fmt).list_sequences(_existing_dir(root))


def read_sequence(fmt: str, root: str | Path, name: str, **options) -> EvalSequence:
    return reader(fmt).read_sequence(_existing_dir(root), name, **options)


def detect_format(root: str | Path) -> str:
    """Guess the format of a dataset folder from its layout; raises naming the formats it knows."""
    root = _existing_dir(root)
    npz = sorted(root.glob("*.npz")) or [p for s in tapvid3d.SUBSETS for p in sorted((root / s).glob("*.npz"))]
    if npz:
        try:
            with np.load(npz[0], allow_pickle=False) as data:
                keys = set(data.files)
        except (OSError, ValueError) as err:
            raise UserError(f"cannot read {npz[0]}: {err}") from None
        if "tracks_XYZ" in keys:
            return "tapvid3d"
        if {"rgb", "depth", "cam_to_world"} <= keys:
            return "synthetic"
    layouts = (
        ("sintel", lambda: (root / "depth").is_dir() or (root / "training" / "depth").is_dir()),
        ("bonn", lambda: any(p.name.startswith(bonn.PREFIX) for p in root.iterdir())),
        ("kitti", lambda: any((c / d).is_dir() for c in (root, root / kitti.SELECTION,
                                                         root / "depth_selection" / kitti.SELECTION)
                              for d in ("groundtruth_depth", "groundtruth_depth_gathered"))),
        ("scannet", lambda: any((p / "pose").is_dir() for p in root.iterdir())),
        ("re10k", lambda: re10k.sequence_folder(root) is not None),
    )
    for name, matches in layouts:
        if matches():
            return name
    raise UserError(f"cannot tell the dataset format of {root}; pass --format (one of {sorted(FORMATS)})")


def _existing_dir(root: str | Path) -> Path:
    root = Path(root)
    if not root.is_dir():
        raise UserError(f"dataset folder not found: {root}")
    return root
