"""The reconstruction layer over the model (random weights: shapes and plumbing, not accuracy), and
its input errors."""

import numpy as np
import pytest
import torch

from d4rt import D4RT, D4RTConfig, Reconstruction
from d4rt.errors import UserError


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return D4RT(D4RTConfig.preset("tiny")).eval()


def test_model_reconstruct_gives_every_output(model):
    video = (np.random.default_rng(0).random((6, 30, 40, 3)) * 255).astype(np.uint8)
    rec = model.reconstruct(video, grid=8)
    d = rec.depth()
    assert d.depth.shape == (6, 30, 40) and np.isfinite(d.depth).all() and (d.confidence > 0).all()
    assert rec.depth(resolution="encoder").depth.shape == (6, 55, 74)  # 64 x 64 pixels at 4:3
    cams = rec.cameras()
    assert cams.intrinsics.shape == (6, 3, 3) and cams.cam_to_world.shape == (6, 4, 4)
    r = cams.cam_to_world[:, :3, :3]
    assert np.allclose(r @ r.transpose(0, 2, 1), np.eye(3), atol=1e-9) and np.allclose(cams.cam_to_world[0], np.eye(4))
    tr = rec.tracks([[0, 5, 5], [5, 39, 29]], frame="world")
    assert tr.points.shape == (2, 6, 3) and np.isfinite(tr.points).all()
    pc = rec.point_cloud(stride=5)
    assert pc.points.shape[1] == 3 and len(pc.points) == len(pc.colors) == 6 * 6 * 8


def test_long_videos_are_encoded_window_by_window(model, monkeypatch):
    video = (np.random.default_rng(1).random((30, 24, 24, 3)) * 255).astype(np.uint8)  # tiny: 24 frames max
    calls = []
    original = model.encode

    def counting_encode(v):
        calls.append(len(v))
        return original(v)

    monkeypatch.setattr(model, "encode", counting_encode)
    rec = model.reconstruct(video, grid=6)
    assert rec.windows == [(0, 24), (6, 30)]
    cams = rec.cameras()
    assert np.isfinite(cams.cam_to_world).all() and cams.cam_to_world.shape == (30, 4, 4)
    assert np.isfinite(rec.depth().depth).all()
    assert set(calls) == {24} and len(calls) >= 2  # whole windows only, never the whole video


def test_dense_tracking_of_a_long_video_encodes_each_window_once(model, monkeypatch):
    video = (np.random.default_rng(2).random((30, 24, 24, 3)) * 255).astype(np.uint8)
    calls = []
    original = model.encode
    monkeypatch.setattr(model, "encode", lambda v: calls.append(len(v)) or original(v))
    rec = model.reconstruct(video, grid=6)
    dense = rec.dense_tracks(resolution=(6, 6), batch_size=64)
    assert dense.coverage == 1.0 and dense.tracks.points.shape == (len(dense.sources), 30, 3)
    assert len(calls) == len(rec.windows) == 2  # kept for the whole run, not re-encoded per batch
    assert len(rec.source._cache) <= rec.source.cache_windows  # the usual cache size afterwards


def test_windows_are_kept_within_the_byte_budget(model):
    """A long video's recipes sweep the windows again and again: with the default budget each window is
    encoded once; with no budget only the two most recent are kept and the sweeps re-encode them."""
    from d4rt.reconstruction.sources import encoded_bytes

    video = (np.random.default_rng(3).random((60, 16, 16, 3)) * 255).astype(np.uint8)
    counts = {}
    for budget in (None, 0):
        rec = Reconstruction.from_model(model, video, grid=4, progress=False)
        if budget is not None:
            rec.source.cache_bytes = budget
        rec.depth(resolution=(4, 4))
        rec.cameras()
        rec.tracks([[0, 3, 3], [59, 10, 10]])
        counts[budget] = rec.source.encodes
        assert len(rec.source._cache) >= 2
        if budget == 0:
            assert len(rec.source._cache) == 2
    assert len(rec.windows) == 3 and counts[None] == 3 and counts[0] > 3, counts
    assert 0 < encoded_bytes(next(iter(rec.source._cache.values()))) < 20e6


def test_bad_inputs_fail_clearly(room_clip):
    with pytest.raises(UserError, match="covers 8 frames but the video has 7"):
        Reconstruction(room_clip.oracle, room_clip.rgb[:7])
    with pytest.raises(UserError, match=r"\(T, H, W, 3\)"):
        Reconstruction(room_clip.oracle, room_clip.rgb[..., 0])
    rec = room_clip.reconstruction()
    with pytest.raises(UserError, match="reference_frame"):
        rec.cameras(reference_frame=8)
    with pytest.raises(UserError, match="resolution"):
        rec.depth(resolution=(0, 5))
    with pytest.raises(UserError, match="no encoder resolution"):
        rec.depth(resolution="encoder")
    with pytest.raises(UserError, match="frame must be"):
        rec.tracks([[0, 1, 1]], frame="global")
