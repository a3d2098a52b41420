"""The named benchmarks of ``d4rt eval``: which data, which tasks and which protocol settings.

Settings follow the published evaluations (shared/reference/evaluation.md): video depth is aligned
per sequence ("scale" and "scale&shift" are both reported, like the D4RT paper's tables), Sintel caps
depth at 70 and clips predictions to 70 after alignment, Bonn caps at 70 and uses frames 30..139, KITTI
has no cap; camera poses use evo's Sim(3)-aligned ATE / RPE; TAPVid-3D uses median scaling and averages
videos, then subsets. Real benchmarks read the user's copy of the dataset (``--data``); the synthetic
benchmark is regenerated from its definition.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from d4rt.errors import UserError
from d4rt.evaluation import readers, synthetic_benchmark
from d4rt.evaluation.sequence import EvalSequence

TASKS = ("depth", "pose", "tracks", "world_tracks", "point_cloud")

SINTEL_SEQUENCES = ("alley_2", "ambush_4", "ambush_5", "ambush_6", "cave_2", "cave_4", "market_2", "market_5",
                    "market_6", "shaman_3", "sleeping_1", "sleeping_2", "temple_2", "temple_3")
BONN_SEQUENCES = ("balloon2", "crowd2", "crowd3", "person_tracking2", "synchronous")


@dataclass(frozen=True)
class Benchmark:
    """A benchmark: the reader format of its data (None: generated), the tasks it scores and how.

    sequences: the published subset (None: every sequence found). read_options: keyword arguments for
    the reader (frame selections). group_by_subset: names are ``<subset>/<video>`` and track metrics
    are averaged over videos within a subset, then over subsets (TAPVid-3D).
    """

    name: str
    description: str
    format: str | None
    tasks: tuple[str, ...]
    depth_alignments: tuple[str, ...] = ("scale", "scale&shift")
    max_depth: float | None = None
    clip_max: float | None = None
    sequences: tuple[str, ...] | None = None
    read_options: tuple[tuple[str, object], ...] = ()
    track_scaling: str = "median"
    group_by_subset: bool = False

    @property
    def needs_data(self) -> bool:
        return self.format is not None

    def sequence_names(self, data: Path | None) -> list[str]:
        """The sequences to evaluate, in order; names missing from ``data`` are an error."""
        if not self.needs_data:
            return [spec.name for spec in synthetic_benchmark.clip_specs()]
        if data is None:
            raise UserError(f"benchmark {self.name} reads your copy of the dataset: pass --data DIR")
        found = readers.list_sequences(self.format, data)
        if self.sequences is None:
            return found
        missing = [s for s in self.sequences if s not in found]
        if missing:
            raise UserError(f"{data} lacks {len(missing)} sequence(s) of the {self.name} benchmark: {missing}")
        return list(self.sequences)

    def load(self, data: Path | None, name: str) -> EvalSequence:
        """Read (or, for the synthetic benchmark, render) one sequence."""
        if not self.needs_data:
            spec = next(s for s in synthetic_benchmark.clip_specs() if s.name == name)
            return spec.render()
        return readers.read_sequence(self.format, data, name, **dict(self.read_options))


BENCHMARKS = {b.name: b for b in (
    Benchmark(synthetic_benchmark.NAME, "48 synthetic dynamic clips with exact ground truth (regenerated)",
              None, TASKS),
    Benchmark("sintel", "MPI Sintel, the 14-sequence video-depth / pose subset", "sintel",
              ("depth", "pose", "point_cloud"), max_depth=70.0, clip_max=70.0, sequences=SINTEL_SEQUENCES),
    Benchmark("bonn", "Bonn RGB-D Dynamic, 5 sequences, frames 30..139", "bonn", ("depth",), max_depth=70.0,
              sequences=BONN_SEQUENCES, read_options=(("frames", slice(30, 140)),)),
    Benchmark("kitti", "KITTI depth selection (validation), one sequence per drive", "kitti", ("depth",)),
    Benchmark("scannet", "ScanNet v2 scenes, every 3rd frame, 90 frames", "scannet",
              ("depth", "pose", "point_cloud"), read_options=(("stride", 3), ("max_frames", 90))),
    Benchmark("re10k", "RealEstate10K camera poses (pose AUC@30), at most 24 frames per sequence", "re10k", ("pose",),
              read_options=(("max_frames", 24),)),
    Benchmark("tapvid3d", "TAPVid-3D (adt / drivetrack / pstudio), camera-frame 3D tracks", "tapvid3d",
              ("tracks", "world_tracks"), group_by_subset=True),
)}


def get_benchmark(name: str) -> Benchmark:
    if name not in BENCHMARKS:
        raise UserError(f"unknown benchmark {name!r}; known: {sorted(BENCHMARKS)}")
    return BENCHMARKS[name]


def folder_benchmark(data: Path, fmt: str | None = None) -> Benchmark:
    """A benchmark over every sequence of a dataset folder (format detected unless given), scoring every
    task its ground truth supports, with the default protocol settings and no depth cap."""
    fmt = fmt or readers.detect_format(data)
    readers.reader(fmt)  # validates the name
    return Benchmark(f"{fmt}:{Path(data).name}", f"every sequence of {data} ({fmt} layout)", fmt, TASKS,
                     group_by_subset=fmt == "tapvid3d")
