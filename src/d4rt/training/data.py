"""The training sample stream: which clip every rank trains on at every step, resumable exactly.

All ranks read one global stream of samples. Global sample ``g`` is item ``perm_e[g mod L]`` of the
dataset in epoch ``e = g div L`` (L = dataset length, ``perm_e`` a permutation drawn from
``(seed, e)``). A training step consumes ``G = batch_size * grad_accum * world_size`` consecutive samples;
micro-step ``m`` of rank ``r`` takes ``batch_size`` of them at offset ``(m * world_size + r) * batch_size``.
Since every sample is a deterministic function of (seed, epoch, index) (see
:class:`d4rt.data.ClipQueryDataset`), the data position is just the index of the next global sample,
which checkpoints store: resuming continues with exactly the samples an uninterrupted run would see.
With data echoing (``echo`` > 1, :class:`d4rt.data.DatasetConfig`) global sample ``g`` is repeat ``g mod echo``
of the clip that sample ``g div echo`` of the plain stream names.
"""

from __future__ import annotations

import random
from collections.abc import Iterator

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import default_collate

from d4rt.config import D4RTConfig
from d4rt.training.stop import defer_stop_signals


class EpochIndexedDataset(torch.utils.data.Dataset):
    """``dataset[(epoch, index)]``: the sample ``index`` of ``epoch`` (works in any worker process,
    whose copy of the dataset gets the epoch set per item). ``dataset`` has ``set_epoch`` and yields
    sample dicts (:class:`d4rt.data.ClipQueryDataset`, :class:`d4rt.data.track_clips.TrackQueryDataset`)."""

    def __init__(self, dataset: torch.utils.data.Dataset):
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, key: tuple[int, int] | tuple[int, int, int]) -> dict:
        epoch, index, *repeat = key
        self.dataset.set_epoch(epoch)
        return self.dataset.sample(index, *repeat) if repeat else self.dataset[index]


class SampleStream(torch.utils.data.Sampler):
    """Infinite batch sampler of one rank: lists of ``(epoch, index)`` keys (``(epoch, index, repeat)`` when
    ``echo`` > 1), one list per micro-step, starting at global sample ``start``."""

    def __init__(self, length: int, seed: int, start: int, batch_size: int, grad_accum: int, rank: int,
                 world_size: int, echo: int = 1):
        self.length, self.seed, self.start, self.echo = length, seed, start, echo
        self.batch_size, self.grad_accum = batch_size, grad_accum
        self.rank, self.world_size = rank, world_size
        self._order: tuple[int, np.ndarray] | None = None

    @property
    def samples_per_step(self) -> int:
        return self.batch_size * self.grad_accum * self.world_size

    def key(self, g: int) -> tuple[int, int] | tuple[int, int, int]:
        """(epoch, dataset index) of global sample ``g``, and its repeat when echoing."""
        if self.echo > 1:
            return (*self._plain_key(g // self.echo), g % self.echo)
        return self._plain_key(g)

    def _plain_key(self, g: int) -> tuple[int, int]:
        epoch, position = divmod(g, self.length)
        if self._order is None or self._order[0] != epoch:
            self._order = (epoch, np.random.default_rng([self.seed, epoch]).permutation(self.length))
        return epoch, int(self._order[1][position])

    def __iter__(self) -> Iterator[list[tuple[int, int]]]:
        step_start = self.start
        while True:
            for micro in range(self.grad_accum):
                first = step_start + (micro * self.world_size + self.rank) * self.batch_size
                yield [self.key(g) for g in range(first, first + self.batch_size)]
            step_start += self.samples_per_step


def seed_worker(worker_id: int) -> None:
    """Seed Python's and NumPy's global generators in a loader worker from its torch seed (which the
    loader derives from the run's seed, rank and worker). The dataset itself uses its own generators."""
    seed = torch.initial_seed() % 2**32
    random.seed(seed)
    np.random.seed(seed)


def init_worker(worker_id: int) -> None:
    """A loader worker's set-up: leave SIGTERM / SIGINT to the main process first (a signal to the process
    group must not kill the workers of a run that is finishing its step), then :func:`seed_worker`."""
    defer_stop_signals()
    seed_worker(worker_id)


def collate_samples(samples: list[dict]) -> dict:
    """Stack sample dicts into a batch. Original-resolution frames (``patch_video``, whose crops differ in size
    from clip to clip) are padded with zeros at the bottom and right to the batch's largest; each clip's own
    (h, w) stays in ``patch_size`` (B, 2), which the patch sampler reads (:func:`model_inputs`)."""
    if "patch_video" in samples[0]:
        height = max(s["patch_video"].shape[1] for s in samples)
        width = max(s["patch_video"].shape[2] for s in samples)
        samples = [s | {"patch_video": F.pad(s["patch_video"], (0, 0, 0, width - s["patch_video"].shape[2],
                                                                  0, height - s["patch_video"].shape[1]))}
                   for s in samples]
    return default_collate(samples)


def model_inputs(config: D4RTConfig, batch: dict) -> dict:
    """The inputs of :meth:`d4rt.model.D4RT.forward` beyond video, queries and aspect ratio that a model with
    ``config`` takes from a batch: ``patch_video`` and ``patch_sizes`` when it cuts its RGB patches from the
    original-resolution frames (the forward pass says so in one line if the batch lacks them), else none."""
    if not config.patches_from_original or "patch_video" not in batch:
        return {}
    return {"patch_video": batch["patch_video"], "patch_sizes": batch["patch_size"]}


def training_loader(dataset: torch.utils.data.Dataset, stream: SampleStream, workers: int, seed: int, rank: int,
                    pin_memory: bool, spawn: bool = False) -> torch.utils.data.DataLoader:
    """A DataLoader over ``stream`` with ``workers`` processes; batches are dicts of stacked tensors.
    Create its iterator (which starts the workers) where SIGTERM / SIGINT are handled (inside
    :class:`d4rt.training.stop.StopRequest`), so that forked workers never hold the default handlers.
    ``spawn``: start the workers with "spawn" instead of the platform's default (fork on Linux), needed when
    they use CUDA (a dataset that renders on the GPU); each then imports torch afresh (seconds, once)."""
    generator = torch.Generator().manual_seed(seed * 1_000_003 + rank)
    context = torch.multiprocessing.get_context("spawn") if spawn and workers else None
    return torch.utils.data.DataLoader(
        EpochIndexedDataset(dataset), batch_sampler=stream, num_workers=workers, pin_memory=pin_memory,
        collate_fn=collate_samples,
        worker_init_fn=init_worker, generator=generator, persistent_workers=False,
        prefetch_factor=2 if workers else None, multiprocessing_context=context)
