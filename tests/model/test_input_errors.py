"""Bad input raises a one-line UserError naming the problem; nothing is clamped."""

import pytest
import torch

from d4rt.errors import UserError


@pytest.fixture(scope="module")
def scene(tiny_model):
    return tiny_model.encode(torch.zeros(5, 16, 24, 3, dtype=torch.uint8))


def one_line(err: pytest.ExceptionInfo) -> str:
    message = str(err.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize("query, message", [
    ([1.0001, 0.5, 0, 0, 0], r"\(u, v\) = \(1\.0001, 0\.5\) outside \[0, 1\]"),
    ([0.5, -0.01, 0, 0, 0], r"outside \[0, 1\]"),
    ([0.5, 0.5, 5, 0, 0], r"t_src = 5 but the clip has 5 frames \(valid 0\.\.4\)"),
    ([0.5, 0.5, 0, -1, 0], r"t_tgt = -1"),
    ([0.5, 0.5, 0, 0, 7], r"t_cam = 7"),
    ([0.5, 0.5, 0, 1.5, 0], r"non-integer t_tgt = 1\.5"),
    ([float("nan"), 0.5, 0, 0, 0], r"NaN"),
])
def test_out_of_range_queries_raise(scene, query, message):
    queries = torch.tensor([[0.5, 0.5, 0, 0, 0], query])
    with pytest.raises(UserError, match=message) as err:
        scene.query(queries)
    assert "query 1 " in one_line(err)


def test_uv_on_the_border_is_valid(scene):
    corners = torch.tensor([[0.0, 0.0, 0, 0, 0], [1.0, 1.0, 4, 4, 4]])
    assert scene.query(corners)["points"].shape == (2, 3)


@pytest.mark.parametrize("queries, message", [
    (torch.zeros(3, 4), r"shape \(N, 5\)"),
    (torch.zeros(2, 3, 5), r"shape \(N, 5\)"),
    (torch.zeros(3, 5, dtype=torch.long), "float tensor"),
    ([[0.5, 0.5, 0, 0, 0]], "torch.Tensor or numpy"),
])
def test_badly_shaped_queries_raise(scene, queries, message):
    with pytest.raises(UserError, match=message) as err:
        scene.query(queries)
    one_line(err)


@pytest.mark.parametrize("video, message", [
    (torch.zeros(4, 16, 16), r"\(T, H, W, 3\)"),
    (torch.zeros(4, 16, 16, 4), "3 RGB channels"),
    (torch.zeros(1, 4, 16, 16, 3), r"\(T, H, W, 3\)"),
    (torch.zeros(4, 16, 16, 3, dtype=torch.int16), "uint8"),
    (torch.full((2, 8, 8, 3), 1.5), r"\[0, 1\]"),
    (torch.full((2, 8, 8, 3), -0.1), r"\[0, 1\]"),
    (torch.full((2, 8, 8, 3), float("nan")), "NaN"),
    (torch.zeros(0, 8, 8, 3), "empty"),
    (torch.zeros(25, 8, 8, 3), "25 frames but this model takes at most 24"),
])
def test_bad_videos_raise(tiny_model, video, message):
    with pytest.raises(UserError, match=message) as err:
        tiny_model.encode(video)
    one_line(err)


def test_training_forward_checks_its_inputs(tiny_model):
    video = torch.rand(2, 4, 64, 64, 3)
    queries = torch.rand(2, 3, 5)
    queries[..., 2:] = 0
    aspect = torch.ones(2)
    with pytest.raises(UserError, match="multiples of patch_size"):
        tiny_model(torch.rand(2, 4, 60, 64, 3), queries, aspect)
    with pytest.raises(UserError, match="at most image_size"):
        tiny_model(torch.rand(2, 4, 72, 64, 3), queries, aspect)
    with pytest.raises(UserError, match=r"aspect_ratio must have shape \(2,\)"):
        tiny_model(video, queries, torch.ones(3))
    with pytest.raises(UserError, match="finite and positive"):
        tiny_model(video, queries, torch.tensor([1.0, 0.0]))
    with pytest.raises(UserError, match="batch"):
        tiny_model(video, queries[:1], aspect)
    bad = queries.clone()
    bad[1, 2, 3] = 4
    with pytest.raises(UserError, match=r"query \(1, 2\) has t_tgt = 4 but the clip has 4 frames"):
        tiny_model(video, bad, aspect)
    with pytest.raises(UserError, match="training video must be float"):
        tiny_model((video * 255).to(torch.uint8), queries, aspect)
    with pytest.raises(UserError, match="queries is on meta but the model is on cpu"):
        tiny_model(video, queries.to("meta"), aspect)


def test_original_patch_source_requires_the_original_frames(make_model):
    model = make_model(rgb_patch_source="original")
    queries = torch.zeros(1, 2, 5)
    with pytest.raises(UserError, match="needs patch_video"):
        model(torch.rand(1, 2, 64, 64, 3), queries, torch.ones(1))
    with pytest.raises(UserError, match="patch_video must have the video's batch and frames"):
        model(torch.rand(1, 2, 64, 64, 3), queries, torch.ones(1), patch_video=torch.rand(1, 3, 90, 60, 3))


def test_bad_chunk_size(scene):
    with pytest.raises(UserError, match="chunk_size"):
        scene.query(torch.zeros(1, 5), chunk_size=0)
