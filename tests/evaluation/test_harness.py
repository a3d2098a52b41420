"""The harness, the baselines and ``d4rt eval`` end to end."""

import json

import numpy as np
from PIL import Image
import pytest
import torch

from d4rt.cli import main
from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.evaluation import synthetic_benchmark
from d4rt.evaluation.baselines import ConstantDepthPredictor, OraclePredictor, make_baseline
from d4rt.evaluation.benchmarks import folder_benchmark, get_benchmark
from d4rt.evaluation.harness import evaluate_sequence, run_benchmark
from d4rt.evaluation.metrics import pose_metrics
from d4rt.evaluation.predictions import Prediction
from d4rt.model import D4RT
from d4rt.synthetic import render_clip
from tests.evaluation.layouts import write_re10k, write_sintel


@pytest.fixture(scope="module")
def synthetic_sequence():
    return get_benchmark(synthetic_benchmark.NAME).load(None, "clip_00")


def test_metrics_respond_to_errors(synthetic_sequence):
    """Starting from the oracle's perfect prediction, each kind of error moves its own metrics only."""
    benchmark = get_benchmark(synthetic_benchmark.NAME)
    seq = synthetic_sequence
    perfect = OraclePredictor().predict(seq, set(benchmark.tasks))
    rng = np.random.default_rng(0)
    wrong = Prediction(
        depth=perfect.depth * 3.0 + 1.0,  # affine: only "scale&shift" forgives it
        cam_to_world=perfect.cam_to_world.copy(),
        tracks=perfect.tracks + rng.normal(0, 0.05, perfect.tracks.shape),
        track_visible=~perfect.track_visible,
        world_tracks=perfect.world_tracks * 2.0,  # a global scale: median scaling forgives it
        point_map=perfect.point_map,
    )
    wrong.cam_to_world[5:, :3, 3] += [0.2, 0.0, 0.0]  # a jump in the trajectory
    m = evaluate_sequence(benchmark, seq, wrong).metrics
    assert m["abs_rel[scale&shift]"] < 1e-6 and m["abs_rel[scale]"] > 0.01
    assert m["ate"] > 0.01 and m["rpe_trans"] > 0.01 and m["rpe_rot"] < 1e-6 and m["auc@30"] < 1
    assert m["apd3d"] < 1 and m["oa"] == 0.0 and m["aj"] == 0.0
    assert m["world_apd3d"] == 1.0
    constant = evaluate_sequence(benchmark, seq, ConstantDepthPredictor().predict(seq, set(benchmark.tasks)))
    assert constant.metrics["abs_rel[scale]"] > 0.1 and constant.metrics["ate"] is None


def test_colmap_baseline_registers_frames_of_a_textured_clip(synthetic_sequence):
    pytest.importorskip("pycolmap")
    seq = synthetic_sequence
    prediction = make_baseline("colmap").predict(seq, {"pose"})
    registered = prediction.registered
    assert registered.sum() >= 3
    assert prediction.notes == [] if registered.all() else "registered" in prediction.notes[0]
    # A real reconstruction: the registered cameras follow the true path to a small fraction of its length.
    m = pose_metrics(prediction.cam_to_world[registered], seq.cam_to_world[registered])
    path = np.linalg.norm(np.diff(seq.cam_to_world[registered, :3, 3], axis=0), axis=1).sum()
    assert m["ate"] < 0.2 * path and m["rpe_rot"] < 10.0
    row = evaluate_sequence(get_benchmark(synthetic_benchmark.NAME), seq, prediction)
    assert row.metrics["registered"] == registered.mean() and row.metrics["abs_rel[scale]"] is None


def test_a_dataset_in_its_published_layout_through_the_harness(tmp_path):
    """Sintel files on disk -> reader -> oracle baseline (ground-truth arrays) -> perfect scores."""
    write_sintel(tmp_path, "alley_2", 4)
    write_sintel(tmp_path, "cave_2", 3)
    benchmark = folder_benchmark(tmp_path)
    assert benchmark.format == "sintel"
    (result,) = run_benchmark(benchmark, [OraclePredictor()], tmp_path, progress=False)
    assert [r.name for r in result.rows] == ["alley_2", "cave_2"]
    agg = result.aggregate
    assert agg["abs_rel[scale]"] < 1e-12 and agg["ate"] < 1e-9 and agg["pc_l1"] < 1e-9 and agg["auc@30"] == 1.0
    assert agg["apd3d"] is None  # Sintel has no tracks
    with pytest.raises(UserError, match="lacks 12 sequence"):
        get_benchmark("sintel").sequence_names(tmp_path)


def test_re10k_pose_auc_through_the_harness(tmp_path):
    """RealEstate10K camera files and frames -> the re10k benchmark -> pose metrics only, perfect for the oracle."""
    for seq in ("0a1b2c", "ffee00"):
        write_re10k(tmp_path, seq, 5)
    benchmark = get_benchmark("re10k")
    assert benchmark.sequence_names(tmp_path) == ["0a1b2c", "ffee00"]
    oracle, still = run_benchmark(benchmark, [OraclePredictor(), make_baseline("static-camera")], tmp_path,
                                  progress=False)
    assert oracle.aggregate["auc@30"] == 1.0 and oracle.aggregate["ate"] < 1e-9
    assert not any(k.startswith("abs_rel") for k in oracle.aggregate)  # a pose benchmark: no depth columns
    assert still.aggregate["auc@30"] < 1.0


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    torch.manual_seed(0)
    directory = tmp_path_factory.mktemp("ckpt")
    D4RT(D4RTConfig.preset("tiny")).save_pretrained(directory)
    return directory


def test_cli_eval_with_a_checkpoint(tmp_path, tiny_checkpoint, capsys):
    data = tmp_path / "clips"
    for i in range(2):
        render_clip(i, 4, 24, 32, camera_motion="truck", num_objects=3).save(data / f"clip_{i}.npz")
    out = tmp_path / "results.json"
    assert main(["eval", "--data", str(data), "--checkpoint", str(tiny_checkpoint), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| d4rt |" in printed and "| oracle |" in printed and "| constant-depth |" in printed
    assert "### d4rt" in printed and "| clip_1 |" in printed and f"wrote {out}" in printed
    results = json.loads(out.read_text())
    methods = {m["name"]: m for m in results["methods"]}
    # The pose floors run by default beside the depth floor, as the synthetic folder scores poses.
    assert list(methods) == ["d4rt", "oracle", "constant-depth", "static-camera", "constant-velocity"]
    d4rt = methods["d4rt"]
    assert [s["name"] for s in d4rt["sequences"]] == ["clip_0", "clip_1"]
    # Each row carries its weight in the pooled depth figures: every pixel of these clips has a true depth.
    assert [s["valid_pixels"] for s in d4rt["sequences"]] == [4 * 24 * 32] * 2
    # Random weights: numbers are finite and imperfect; the oracle beside them is perfect.
    for key in ("abs_rel[scale&shift]", "ate", "apd3d", "world_l1", "pc_l1"):
        assert np.isfinite(d4rt["aggregate"][key]), key
    assert d4rt["aggregate"]["abs_rel[scale]"] > 1e-3
    assert methods["oracle"]["aggregate"]["apd3d"] == 1.0
    assert results["benchmark"]["format"] == "synthetic"
    # The figure beside the JSON: error by confidence decile, AbsRel per sequence.
    assert f"wrote {out.with_suffix('.png')}" in printed
    with Image.open(out.with_suffix(".png")) as image:
        assert image.size[0] > 1000


@pytest.mark.slow(seconds=40)
def test_a_stopped_eval_resumes_to_the_same_json(tmp_path, tiny_checkpoint, monkeypatch, capsys):
    """Rows are kept as they finish; --resume reuses them (without predicting again) and writes the same JSON."""
    from d4rt.evaluation import harness

    data = tmp_path / "clips"
    for i in range(3):
        render_clip(i, 4, 24, 32, camera_motion="truck", num_objects=3).save(data / f"clip_{i}.npz")
    args = ["eval", "--data", str(data), "--checkpoint", str(tiny_checkpoint), "--no-progress"]
    straight = tmp_path / "straight.json"
    assert main(args + ["--out", str(straight)]) == 0
    assert not (tmp_path / "straight.json.partial").exists()  # removed once the JSON is written

    # A run killed while scoring the third clip: its first two clips' rows are on disk.
    out = tmp_path / "stopped.json"
    evaluate = harness.evaluate_sequence
    def killed_on_clip_2(benchmark, sequence, prediction):
        if sequence.name == "clip_2":
            raise KeyboardInterrupt
        return evaluate(benchmark, sequence, prediction)
    monkeypatch.setattr(harness, "evaluate_sequence", killed_on_clip_2)
    assert main(args + ["--out", str(out)]) == 130  # Ctrl-C: "d4rt eval: interrupted"
    monkeypatch.setattr(harness, "evaluate_sequence", evaluate)
    methods = 5  # d4rt and the default baselines: oracle, constant-depth, static-camera, constant-velocity
    assert not out.exists() and len(list((tmp_path / "stopped.json.partial").glob("*.json"))) == 1 + 2 * methods

    scored = []
    def counted(benchmark, sequence, prediction):
        scored.append(sequence.name)
        return evaluate(benchmark, sequence, prediction)
    monkeypatch.setattr(harness, "evaluate_sequence", counted)
    capsys.readouterr()
    assert main(args + ["--out", str(out), "--resume"]) == 0
    assert scored == ["clip_2"] * methods and f"{2 * methods} finished rows reused" in capsys.readouterr().out
    assert json.loads(out.read_text())["methods"] == json.loads(straight.read_text())["methods"]

    # Rows of another checkpoint are refused in one line, not mixed in.
    monkeypatch.setattr(harness, "evaluate_sequence", killed_on_clip_2)
    assert main(args + ["--out", str(out)]) == 130
    other = tmp_path / "other"
    torch.manual_seed(1)
    D4RT(D4RTConfig.preset("tiny")).save_pretrained(other)
    capsys.readouterr()
    assert main(["eval", "--data", str(data), "--checkpoint", str(other), "--out", str(out), "--resume"]) == 2
    assert "holds rows of a different d4rt (its checkpoint or camera recipe changed)" in capsys.readouterr().err
    # Without --resume a stale folder is cleared, not reused.
    monkeypatch.setattr(harness, "evaluate_sequence", counted)
    scored.clear()
    assert main(["eval", "--data", str(data), "--checkpoint", str(other), "--out", str(out), "--no-progress"]) == 0
    assert len(scored) == 3 * methods


def test_confidence_error_samples_follow_the_sequence_alignment():
    from d4rt.evaluation.harness import confidence_error_samples
    from d4rt.evaluation.metrics.depth import evaluate_depth

    rng = np.random.default_rng(1)
    gt = rng.uniform(1, 5, (3, 20, 30))
    gt[0, 0, :5] = 0  # no ground truth there
    confidence = rng.uniform(0.1, 1, gt.shape)
    pred = 0.5 * gt + 0.2  # exact up to scale and shift
    pred[1, 4, 4] = 100.0  # one bad pixel
    fit = evaluate_depth(pred, gt, "scale&shift")
    samples = confidence_error_samples(pred, confidence, gt, fit, count=10_000)
    assert samples.shape == (3 * 20 * 30 - 5, 2)
    assert np.sort(samples[:, 1])[-2] < 1e-6 and samples[:, 1].max() > 10  # only the bad pixel is wrong
    assert len(confidence_error_samples(pred, confidence, gt, fit, count=100)) == 100


def test_cli_errors(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # where the default output (and its .partial folder) would go
    assert main(["eval", "--benchmark", "sintel", "--baseline", "oracle"]) == 2
    assert "pass --data DIR" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())  # refused before anything was written
    assert main(["eval", "--benchmark", synthetic_benchmark.NAME]) == 2
    assert "pass --checkpoint and/or --baseline" in capsys.readouterr().err
    assert main(["eval", "--data", str(tmp_path), "--baseline", "oracle"]) == 2
    assert "cannot tell the dataset format" in capsys.readouterr().err
    assert main(["eval", "--benchmark", synthetic_benchmark.NAME, "--data", str(tmp_path), "--baseline", "oracle"]) == 2
    assert "drop --data" in capsys.readouterr().err
