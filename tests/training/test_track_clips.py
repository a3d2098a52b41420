"""Bring your own data with per-point tracks: samples match the synthetic oracle's exact answers, and a
run trains on them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from d4rt.data import AugmentConfig
from d4rt.errors import UserError
from d4rt.evaluation.readers.synthetic import oracle_tracks
from d4rt.geometry.transforms import apply_transform
from d4rt.geometry.view import View
from d4rt.synthetic import render_clip
from d4rt.training import TrainConfig, train
from d4rt.data.track_clips import (TrackClip, TrackDatasetConfig, TrackQueryDataset, load_track_clip,
                                   track_training_sample)
from training_helpers import fast_config


@pytest.fixture(scope="module")
def synthetic():
    return render_clip(5, 6, 40, 48, num_objects=4, moving_fraction=1.0, camera_motion="orbit")


def as_track_clip(clip, num_tracks=400) -> TrackClip:
    """Exact oracle tracks of a synthetic clip, stored as world positions: a dataset without body poses."""
    tracks = oracle_tracks(clip, num_tracks, seed=1)
    world = apply_transform(clip.cam_to_world[:, None], tracks.points)  # (T, N, 3) camera -> world
    return TrackClip(clip.rgb, clip.intrinsics, clip.cam_to_world, world.transpose(1, 0, 2), tracks.visible.T)


def compare_with_oracle(sample: dict, oracle) -> None:
    truth = oracle.query(sample["queries"].double())
    valid = sample["valid"]
    assert valid.float().mean() > 0.9 and torch.equal(valid, truth["valid"])
    # (u, v, t_src) is the tracked point's projection; casting that pixel's ray finds the same point. The
    # queries are float32, so a point exactly on a silhouette could land on the neighbouring surface.
    close = (sample["points"][valid].double() - truth["points"][valid]).norm(dim=-1) < 1e-5 * truth["points"][valid].norm(dim=-1)
    assert close.float().mean() > 0.99
    for key in ("uv", "motion"):
        err = (sample[key][valid][close].double() - truth[key][valid][close]).abs().max()
        assert err < 1e-5, key
    agree = sample["visibility"][valid][close] == truth["visibility"][valid][close].float()
    assert agree.float().mean() > 0.99
    assert torch.equal(sample["uv_valid"], truth["uv_valid"]) and not sample["normals_valid"].any()
    t = sample["queries"][:, 2:]
    assert ((t[:, 1] == t[:, 2]).float().mean() > 0.3)  # t_cam = t_tgt forced 40% of the time (+ chance)


def test_track_samples_match_the_exact_oracle(synthetic, tmp_path):
    track_clip = load_track_clip(as_track_clip(synthetic).save(tmp_path / "clip.npz"))
    rng = np.random.default_rng(0)
    full = View.full(synthetic.num_frames, synthetic.height, synthetic.width)
    sample = track_training_sample(track_clip, full, rng, 512, 0.4, AugmentConfig(enabled=False))
    compare_with_oracle(sample, synthetic.oracle)
    # Through a crop, resize and temporal stride (the augmentations' geometry): the view's own oracle.
    view = View((synthetic.height, synthetic.width), (6, 4, 36, 30), (32, 32), (1, 3, 5))
    sample = track_training_sample(track_clip, view, rng, 512, 0.4, AugmentConfig(enabled=False))
    assert sample["video"].shape == (3, 32, 32, 3)
    compare_with_oracle(sample, synthetic.view(view).oracle)


def test_training_on_track_clips(synthetic, tmp_path):
    data = tmp_path / "tracks"
    as_track_clip(synthetic).save(data / "a.npz")
    config = fast_config(tmp_path, data={"batch_size": 1, "workers": 0, "tracks": {
        "directory": str(data), "frames": 4, "size": [32, 32], "num_queries": 64}}, run={"max_steps": 2})
    result = train(TrainConfig.from_dict(config), tmp_path / "run")
    assert result.step == 2 and np.isfinite(result.metrics["loss/total"])
    assert result.metrics["loss/normal"] == 0.0  # no normals in track data: the term is masked out


def test_bad_track_clips_are_refused(tmp_path):
    with pytest.raises(UserError, match="tracks has shape"):
        TrackClip(np.zeros((2, 8, 8, 3)), np.zeros((2, 3, 3)), np.zeros((2, 4, 4)), np.zeros((5, 3, 3)),
                  np.zeros((5, 2), bool))
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    with pytest.raises(UserError, match="cannot read track clip"):
        load_track_clip(tmp_path / "x.npz")
    with pytest.raises(UserError, match="no .npz track clips"):
        TrackQueryDataset(TrackDatasetConfig(directory=str(tmp_path / "empty")))
