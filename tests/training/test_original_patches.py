"""Training a model whose query RGB patches come from the original-resolution frames (``rgb_patch_source:
original``, the paper's App. C): the samples carry the view's crop at the clip's own resolution, augmented like the
encoder's frames; clips of different sizes are padded into one batch and each keeps its own size."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from d4rt.config import D4RTConfig
from d4rt.data import AugmentConfig, ClipQueryDataset, DatasetConfig, QuerySampler, QuerySamplerConfig
from d4rt.data import make_training_sample
from d4rt.data.augment import _gaussian_blur
from d4rt.errors import UserError
from d4rt.geometry.view import View
from d4rt.model import D4RT
from d4rt.model.query_embedding import sample_rgb_patches
from d4rt.synthetic import render_clip
from d4rt.synthetic.clip import view_rgb
from d4rt.training import TrainConfig, train
from d4rt.training.data import collate_samples, model_inputs
from training_helpers import fast_config

MEAN, STD = torch.tensor([0.485, 0.456, 0.406]), torch.tensor([0.229, 0.224, 0.225])


@pytest.fixture(scope="module")
def clip():
    return render_clip(3, 4, 40, 56, num_objects=2)


def crop_view(clip) -> View:
    """A 30x36 crop of frames 1-3 of the 40x56 clip, resized to 16x16."""
    return View((clip.height, clip.width), (10, 4, 36, 30), (16, 16), (1, 2, 3))


def sample(clip, augment: AugmentConfig, patch_frames: bool, seed: int = 0) -> dict:
    sampler = QuerySampler(QuerySamplerConfig(num_queries=32))
    return make_training_sample(clip, crop_view(clip), np.random.default_rng(seed), sampler, augment, patch_frames)


def test_patch_frames_are_the_views_crop_at_the_clips_own_resolution(clip):
    plain = sample(clip, AugmentConfig(enabled=False), False)
    with_patches = sample(clip, AugmentConfig(enabled=False), True)
    assert torch.equal(with_patches["patch_video"], torch.from_numpy(clip.rgb[[1, 2, 3], 4:34, 10:46]))
    assert with_patches["patch_size"].tolist() == [30, 36]
    assert torch.equal(with_patches["video"], torch.from_numpy(view_rgb(clip.rgb, crop_view(clip))).float() / 255.0)
    # Asking for the frames changes nothing else: the same video, queries and targets from the same draws.
    assert set(with_patches) - set(plain) == {"patch_video", "patch_size"}
    assert all(torch.equal(plain[k], with_patches[k]) for k in plain)


def test_augmented_patch_frames_see_the_same_augmentation(clip):
    augment = AugmentConfig(jitter_prob=1.0, color_drop_prob=0.0, blur_prob=1.0, blur_sigma=(1.0, 1.0))
    for seed in range(3):
        plain = sample(clip, augment, False, seed)
        s = sample(clip, augment, True, seed)
        assert all(torch.equal(plain[k], s[k]) for k in plain)  # the encoder's frames are drawn as before
        # The original-resolution crop, augmented with the same draw and a blur of the same width in the scene,
        # then brought to the view's size, is the view's augmented video up to resampling.
        patch_video = s["patch_video"].float() / 255.0
        down = F.interpolate(patch_video.permute(0, 3, 1, 2), size=(16, 16), mode="bilinear",
                             align_corners=False, antialias=True).permute(0, 2, 3, 1)
        unaugmented = sample(clip, AugmentConfig(enabled=False), True, seed)["patch_video"].float() / 255.0
        assert (down - s["video"]).abs().mean() < 0.005  # 0.02-0.025 with the blur's sigma left unscaled
        assert (patch_video - unaugmented).abs().mean() > 0.02  # it was augmented
    grey = sample(clip, AugmentConfig(jitter_prob=0.0, color_drop_prob=1.0, blur_prob=0.0), True)
    assert torch.equal(grey["patch_video"][..., 0], grey["patch_video"][..., 2])


def test_the_blur_of_finer_frames_is_scaled_along_each_axis():
    impulse = torch.zeros(1, 1, 15, 15)
    impulse[..., 7, 7] = 1.0
    blurred = _gaussian_blur(impulse, 2.0, 0.3)[0, 0]  # wide down the rows, narrow along the columns
    assert blurred[7].sum() < 0.25 and blurred[:, 7].sum() > 0.95
    assert torch.allclose(blurred.sum(), torch.tensor(1.0))


def test_padded_clips_give_each_clip_its_own_patches():
    torch.manual_seed(0)
    small, large = torch.rand(1, 2, 7, 9, 3), torch.rand(1, 2, 12, 10, 3)
    padded = torch.cat([F.pad(small, (0, 0, 0, 1, 0, 5)), large])  # (2, 2, 12, 10, 3)
    uv = torch.tensor([[[0.0, 0.0], [0.5, 0.5], [1.0, 0.97], [0.93, 0.02]]]).expand(2, -1, -1)
    frame = torch.tensor([[0, 1, 1, 0]]).expand(2, -1)
    both = sample_rgb_patches(padded, uv, frame, 5, MEAN, STD, torch.tensor([[7, 9], [12, 10]]))
    assert torch.equal(both[:1], sample_rgb_patches(small, uv[:1], frame[:1], 5, MEAN, STD))
    assert torch.equal(both[1:], sample_rgb_patches(large, uv[1:], frame[1:], 5, MEAN, STD))
    # The query embedding's shared-source path (runs of equal (u, v, t_src)) reads each clip within its own size too.
    model = original_model()
    queries = torch.tensor([[0.9, 0.95, 1.0, 0.0, 0.0], [0.9, 0.95, 1.0, 1.0, 1.0], [0.1, 0.2, 0.0, 1.0, 0.0]])
    queries = queries.expand(2, -1, -1)
    sizes = torch.tensor([[7, 9], [12, 10]])
    with torch.no_grad():
        shared = model.query_embedding(queries, padded, True, sizes)
        alone = torch.cat([model.query_embedding(queries[:1], small, False),
                           model.query_embedding(queries[1:], large, False)])
    torch.testing.assert_close(shared, alone)


def original_model() -> D4RT:
    torch.manual_seed(0)
    config = D4RTConfig.preset("tiny", max_frames=4, image_size=32, rgb_patch_source="original")
    return D4RT(config).eval()


def test_a_collated_batch_answers_as_each_clip_alone():
    config = DatasetConfig(seed=4, frames=4, size=(32, 32), render_pixels=40 * 40, num_clips=8,
                           sampler=QuerySamplerConfig(num_queries=48),
                           augment=AugmentConfig(crop_policy="paper", max_stride=1))
    dataset = ClipQueryDataset(config, patch_frames=True)
    samples = [dataset[i] for i in range(3)]
    assert len({tuple(s["patch_size"].tolist()) for s in samples}) > 1  # crops of different sizes
    model = original_model()
    batch = collate_samples(samples)
    assert batch["patch_size"].shape == (3, 2)
    with torch.no_grad():
        together = model(batch["video"], batch["queries"], batch["aspect_ratio"], **model_inputs(model.config, batch))
        for i, s in enumerate(samples):
            one = collate_samples([s])
            alone = model(one["video"], one["queries"], one["aspect_ratio"], **model_inputs(model.config, one))
            torch.testing.assert_close(together["points"][i], alone["points"][0], rtol=1e-4, atol=1e-5)
    # An encoder-patch model takes nothing from the batch's original frames.
    assert model_inputs(D4RTConfig.preset("tiny"), batch) == {}


def test_forward_refuses_bad_patch_sizes():
    model = original_model()
    video, queries = torch.rand(1, 2, 32, 32, 3), torch.tensor([[[0.5, 0.5, 0.0, 1.0, 1.0]]])
    patch_video, aspect = torch.rand(1, 2, 40, 48, 3), torch.tensor([1.2])
    # The message names the rule and the offending sizes.
    for sizes, message in ((torch.tensor([[41, 48]]), r"within patch_video's \(40, 48\), got \[\[41, 48\]\]"),
                           (torch.tensor([40, 48]), r"must be \(1, 2\).*got \[40, 48\]"),
                           (torch.tensor([[40.0, 48.0]]), r"integer.*\(torch.float32\)")):
        with pytest.raises(UserError, match=message):
            model(video, queries, aspect, patch_video=patch_video, patch_sizes=sizes)
    with pytest.raises(UserError, match="without patch_video"):
        model(video, queries, aspect, patch_sizes=torch.tensor([[40, 48]]))
    with pytest.raises(UserError, match="needs patch_video"):
        model(video, queries, aspect)


def test_training_and_validation_with_original_patches(tmp_path, clip_dir):
    config = fast_config(clip_dir, model={"preset": "tiny", "overrides": {"max_frames": 4,
                                                                           "rgb_patch_source": "original"}},
                         run={"max_steps": 2, "checkpoint_every": 2},
                         validation={"every": 2, "num_clips": 1, "frames": 4, "height": 32, "width": 48,
                                     "num_queries": 64, "track_points": 8, "tasks": ["depth"]})
    config["data"].update(batch_size=2)
    config["data"]["dataset"]["augment"] = {"crop_policy": "paper", "max_stride": 1}
    result = train(TrainConfig.from_dict(config), tmp_path / "run")
    assert np.isfinite(result.metrics["loss/3d"]) and np.isfinite(result.metrics["val/loss/3d"])
    assert D4RT.from_pretrained(tmp_path / "run").config.rgb_patch_source == "original"


def test_trained_weights_can_go_on_with_original_patches(tmp_path, clip_dir):
    """The patch source is an input choice, not architecture: init_from may switch it (the weights load as they are)."""
    train(TrainConfig.from_dict(fast_config(clip_dir, run={"max_steps": 1, "checkpoint_every": 1})), tmp_path / "a")
    start = D4RT.from_pretrained(tmp_path / "a")
    config = fast_config(clip_dir, model={"preset": "tiny", "init_from": str(tmp_path / "a"),
                                          "overrides": {"max_frames": 4, "rgb_patch_source": "original"}},
                         run={"max_steps": 1, "checkpoint_every": 1}, optim={"lr": 1e-12, "min_lr": 1e-12,
                                                                               "warmup_steps": 0})
    train(TrainConfig.from_dict(config), tmp_path / "b")
    after = D4RT.from_pretrained(tmp_path / "b")
    assert after.config == start.config.replace(rgb_patch_source="original")
    assert all(torch.allclose(v, after.state_dict()[k], atol=1e-9) for k, v in start.state_dict().items())


def test_a_run_from_a_checkpoint_keeps_its_calibrated_motion_threshold(tmp_path, clip_dir):
    """The motion-mask threshold is calibrated after training, not learned: a run from a checkpoint that carries one
    (the shipped weights carry 0.2) keeps it, so the shipped weights stay a valid start; a config may set its own."""
    train(TrainConfig.from_dict(fast_config(clip_dir, run={"max_steps": 1, "checkpoint_every": 1})), tmp_path / "a")
    config_path = tmp_path / "a" / "config.json"
    config_path.write_text(json.dumps({**json.loads(config_path.read_text()), "motion_threshold": 0.2}))
    for run, overrides, expected in (("b", {}, 0.2), ("c", {"motion_threshold": 0.1}, 0.1)):
        config = fast_config(clip_dir, model={"preset": "tiny", "init_from": str(tmp_path / "a"),
                                              "overrides": {"max_frames": 4, **overrides}},
                             run={"max_steps": 1, "checkpoint_every": 1})
        train(TrainConfig.from_dict(config), tmp_path / run)
        assert D4RT.from_pretrained(tmp_path / run).config.motion_threshold == expected


def test_a_part_added_through_init_from_gets_the_seeded_fresh_weights(tmp_path, clip_dir):
    """Loading the checkpoint must not move the seeded random stream: a part it lacks (here the dense depth head)
    starts from exactly the weights a fresh model of the same seed has (runs stay reproducible from their config)."""
    train(TrainConfig.from_dict(fast_config(clip_dir, run={"max_steps": 1, "checkpoint_every": 1})), tmp_path / "a")
    overrides = {"max_frames": 4, "dense_depth_head": True}
    config = TrainConfig.from_dict(fast_config(
        clip_dir, model={"preset": "tiny", "init_from": str(tmp_path / "a"), "overrides": overrides},
        run={"max_steps": 1, "checkpoint_every": 1}, optim={"lr": 1e-12, "min_lr": 1e-12, "warmup_steps": 0}))
    train(config, tmp_path / "b")
    torch.manual_seed(config.run.seed)
    fresh = D4RT(D4RTConfig.preset("tiny", **overrides)).dense_depth.state_dict()
    after = D4RT.from_pretrained(tmp_path / "b").dense_depth.state_dict()
    assert all(torch.allclose(v, after[k], atol=1e-9) for k, v in fresh.items())
