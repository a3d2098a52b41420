"""tools/depth_probe.py: the far/near depth ratio by hand, and a probe that scores exact depth as exact."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from d4rt.evaluation.predictions import Prediction
from d4rt.evaluation.sequence import EvalSequence

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "depth_probe.py"
spec = importlib.util.spec_from_file_location("depth_probe", SCRIPT)
depth_probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(depth_probe)


def outdoor_depth() -> np.ndarray:
    """(2, 4, 4): a top half of sky at 50, a bottom half of ground at 2 and 4."""
    depth = np.full((2, 4, 4), 50.0, np.float32)
    depth[:, 2:, :2], depth[:, 2:, 2:] = 2.0, 4.0
    return depth


def test_far_near_ratio_by_hand():
    true = outdoor_depth()
    assert depth_probe.far_near_ratio(true * 3, true) == pytest.approx((50 / 3.0, 50 / 3.0))
    squeezed = np.where(true > 30, 10.0, true)  # the sky 5x too near
    assert depth_probe.far_near_ratio(squeezed, true) == pytest.approx((10 / 3.0, 50 / 3.0))
    room = np.where(true > 30, 6.0, true)  # nothing beyond 30: no ratio
    assert depth_probe.far_near_ratio(room, room) is None
    assert depth_probe.far_near_ratio(-true, true) is None  # a non-positive predicted median has no ratio
    assert depth_probe.far_near_ratio(np.where(true > 30, -1.0, true), true) is None


def test_probe_scores_exact_depth_as_exact_and_a_squeezed_sky_as_such():
    true = outdoor_depth()
    sequence = EvalSequence("outdoor", np.zeros((2, 4, 4, 3), np.uint8), depth=true)
    exact = depth_probe.probe(SimpleNamespace(predict=lambda seq, tasks: Prediction(depth=seq.depth * 2.5)),
                              [sequence])
    assert exact["abs_rel[scale&shift]"] == pytest.approx(0.0, abs=1e-4)
    assert exact["far_near_log_error"] == pytest.approx(0.0, abs=1e-6)
    assert exact["clips"][0]["far_near_ratio"] == {"predicted": 16.667, "true": 16.667}
    assert exact["clips"][0]["valid_pixels"] == true.size  # its weight in the pooled figures (every depth valid)
    squeezed = depth_probe.probe(
        SimpleNamespace(predict=lambda seq, tasks: Prediction(depth=np.where(seq.depth > 30, 10.0, seq.depth))),
        [sequence])
    assert squeezed["far_near_log_error"] == pytest.approx(np.log(5.0), abs=1e-3)


def test_the_clip_order_is_balanced_first_and_covers_the_benchmark_design():
    order = depth_probe.probe_indices()
    assert sorted(order) == list(range(48))  # every definition once: 48 clips as many as the benchmark's
    first = order[:16]
    assert sorted(i // 6 for i in first[:8]) == list(range(8))  # any 8 first: every field-of-view band
    sizes = np.bincount([i % 6 for i in first], minlength=6)
    assert sizes.min() >= 2 and sizes.max() - sizes.min() <= 1  # the first 16: every size, about as often


def test_the_dense_head_predictor_reads_the_heads_depth_at_the_clip_size(tmp_path):
    import torch

    from d4rt.config import D4RTConfig
    from d4rt.errors import UserError
    from d4rt.model import D4RT

    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny", dense_depth_head=True))
    model.save_pretrained(tmp_path / "dense")
    predictor = depth_probe.DenseHeadPredictor(str(tmp_path / "dense"))
    rgb = np.random.default_rng(0).integers(0, 256, (3, 40, 24, 3), dtype=np.uint8)
    sequence = EvalSequence("clip", rgb, depth=np.ones((3, 40, 24), np.float32))
    depth = predictor.predict(sequence, {"depth"}).depth
    scene = predictor.model.encode(rgb)
    with torch.no_grad():
        head = torch.exp(predictor.model.dense_depth(scene.tokens, 3, 64, 64))[0].numpy()
    assert depth.shape == (3, 40, 24) and np.all(depth > 0)
    # Resized bilinearly from the 64x64 encoder grid: every value lies within its frame's range of head depths.
    assert np.all(depth.min((1, 2)) >= head.min((1, 2)) - 1e-5) and np.all(depth.max((1, 2)) <= head.max((1, 2)) + 1e-5)
    D4RT(D4RTConfig.preset("tiny")).save_pretrained(tmp_path / "plain")
    with pytest.raises(UserError, match="has no dense depth head"):
        depth_probe.DenseHeadPredictor(str(tmp_path / "plain"))


def test_skip_leaves_out_the_first_clips_and_a_gate_seed_draws_the_gate_set(monkeypatch):
    from dataclasses import dataclass

    @dataclass
    class Spec:  # stands in for a clip definition: render() says which seed it was given
        index: int
        seed: int

        def render(self):
            return self.seed

    monkeypatch.setattr(depth_probe, "clip_specs", lambda: [Spec(i, i) for i in range(48)])
    monkeypatch.setattr(depth_probe, "gate_specs", lambda gate: [Spec(i, gate + i) for i in range(48)])
    order = depth_probe.probe_indices()
    fresh = depth_probe.render_probe_clips(48, skip=16)
    assert fresh == [depth_probe.HELD_OUT_SEED + i for i in order[16:]]
    assert depth_probe.render_probe_clips(16) == [depth_probe.HELD_OUT_SEED + i for i in order[:16]]
    assert depth_probe.render_probe_clips(32, gate_seed=11_097_000) == [11_097_000 + i for i in order[:32]]


def test_the_windowed_predictor_reads_depth_as_the_stitched_reconstruction(tmp_path):
    import torch

    from d4rt.config import D4RTConfig
    from d4rt.evaluation.predictions import d4rt_predictor
    from d4rt.model import D4RT
    from d4rt.reconstruction import Reconstruction

    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny"))
    model.save_pretrained(tmp_path / "tiny")
    rgb = np.random.default_rng(1).integers(0, 256, (6, 24, 32, 3), dtype=np.uint8)
    sequence = EvalSequence("clip", rgb, depth=np.ones((6, 24, 32), np.float32))
    windowed = d4rt_predictor(str(tmp_path / "tiny"), window=4, overlap=2).predict(sequence, {"depth"}).depth
    whole = d4rt_predictor(str(tmp_path / "tiny")).predict(sequence, {"depth"}).depth
    expected = Reconstruction.from_model(model, rgb, window=4, overlap=2).depth(resolution=(24, 32)).depth
    assert windowed.shape == whole.shape == (6, 24, 32)
    np.testing.assert_allclose(windowed, expected, rtol=1e-5)
    assert not np.allclose(windowed[4:], whole[4:])  # frames 4-5 come from the second window, its own context


@pytest.mark.parametrize("flags, message", [(["--overlap", "2"], "--overlap needs --window"),
                                            (["--window", "1"], "window must be at least 2 frames, got 1"),
                                            (["--window", "8", "--overlap", "8"], "overlap must be between 1 and")])
def test_a_bad_window_is_refused_in_one_line_before_anything_loads(monkeypatch, capsys, flags, message):
    monkeypatch.setattr("sys.argv", ["depth_probe.py", "no-such-checkpoint", "--out", "x.json", *flags])
    with pytest.raises(SystemExit):
        depth_probe.main()
    assert message in capsys.readouterr().err
