"""Training data: the paper's query sampler, geometry-consistent augmentations, torch datasets (synthetic
clips, clip files, and clips with per-point 3D tracks)."""

from d4rt.data.augment import AugmentConfig, photometric_augment, sample_view
from d4rt.data.dataset import ClipQueryDataset, DatasetConfig, make_training_sample
from d4rt.data.sampler import QuerySampler, QuerySamplerConfig, boundary_mask
from d4rt.data.track_clips import TrackClip, TrackDatasetConfig, TrackQueryDataset, load_track_clip


def build_dataset(dataset: DatasetConfig, tracks: TrackDatasetConfig | None = None, patch_frames: bool = False
                  ) -> ClipQueryDataset | TrackQueryDataset:
    """The training dataset a config names: clips with per-point tracks when ``tracks`` is given, else
    the synthetic or clip-file dataset of ``dataset``. ``patch_frames``: samples also carry the original-resolution
    frames (``patch_video``, ``patch_size``) for a model with ``rgb_patch_source="original"``."""
    return (TrackQueryDataset(tracks, patch_frames) if tracks
            else ClipQueryDataset(dataset, patch_frames))


__all__ = [
    "AugmentConfig",
    "ClipQueryDataset",
    "DatasetConfig",
    "QuerySampler",
    "QuerySamplerConfig",
    "TrackClip",
    "TrackDatasetConfig",
    "TrackQueryDataset",
    "build_dataset",
    "load_track_clip",
    "boundary_mask",
    "make_training_sample",
    "photometric_augment",
    "sample_view",
]
