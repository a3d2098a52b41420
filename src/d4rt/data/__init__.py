"""Training data: the paper's query sampler, geometry-consistent augmentations, torch datasets."""

from d4rt.data.augment import AugmentConfig, photometric_augment, sample_view
from d4rt.data.dataset import ClipQueryDataset, DatasetConfig, make_training_sample
from d4rt.data.sampler import QuerySampler, QuerySamplerConfig, boundary_mask

__all__ = [
    "AugmentConfig",
    "ClipQueryDataset",
    "DatasetConfig",
    "QuerySampler",
    "QuerySamplerConfig",
    "boundary_mask",
    "make_training_sample",
    "photometric_augment",
    "sample_view",
]
