"""`d4rt generate` and `d4rt demo` end to end, through the real console entry point."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image
import pytest
import torch

import d4rt
from d4rt.cli import demo
from d4rt.config import D4RTConfig
from d4rt.model import D4RT
from d4rt.synthetic import load_clip, render_clip
from subprocess_budget import budget


def run_cli(*args, cwd=None):
    # The d4rt under test, whatever the working directory (a relative PYTHONPATH would not follow cwd).
    env = {**os.environ, "PYTHONPATH": str(Path(d4rt.__file__).parents[1])}
    return subprocess.run([sys.executable, "-m", "d4rt", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=budget(600), env=env)


def test_generate_writes_clips_reproducibly(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for out in (a, b):
        r = run_cli("generate", "--out", str(out), "--num-clips", "2", "--frames", "3", "--height", "24",
                    "--width", "32", "--seed", "5")
        assert r.returncode == 0, r.stderr
    files = sorted(p.name for p in a.glob("*.npz"))
    assert files == ["clip_00000.npz", "clip_00001.npz"] and (a / "manifest.json").exists()
    for name in files:
        x, y = load_clip(a / name), load_clip(b / name)
        for key in ("rgb", "depth", "normals", "object_ids", "intrinsics", "cam_to_world", "object_to_world"):
            assert getattr(x, key).tobytes() == getattr(y, key).tobytes(), key
    # Clip i is render_clip(seed + i): anyone can regenerate one clip alone.
    again = render_clip(6, 3, 24, 32)
    assert np.array_equal(again.rgb, load_clip(a / "clip_00001.npz").rgb)
    assert "generate" in r.stderr  # the progress bar


def test_generate_rejects_bad_arguments_in_one_line(tmp_path):
    for args, message in [(["--num-clips", "0"], "--num-clips"), (["--num-clips", "1", "--height", "2"], "--height"),
                          (["--num-clips", "1", "--seed", "-1"], "--seed"),
                          (["--num-clips", "1", "--time-stride", "0"], "time_stride")]:
        r = run_cli("generate", "--out", str(tmp_path / "x"), *args)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0] and "Traceback" not in r.stderr, r.stderr
    (tmp_path / "file").write_text("")
    r = run_cli("generate", "--out", str(tmp_path / "file"), "--num-clips", "1")
    assert r.returncode == 2 and "not a directory" in r.stderr


OUTPUTS = ("reconstruction.npz", "depth", "depth.mp4", "points.ply", "scene.glb", "colmap", "trajectory_tum.txt",
           "tracks.mp4", "viewer.html")
CARD_FOCAL = Path(__file__).resolve().parents[2] / "docs" / "model-card" / "focal.json"


def printed_errors(stdout: str) -> dict[str, float]:
    return {name: float(re.search(rf"{name} ([0-9.e+-]+)", stdout).group(1))
            for name in ("AbsRel", "ATE", "focal length error", "APD3D", "L1")}


@pytest.mark.slow(seconds=265)
def test_demo_runs_with_no_arguments(tmp_path):
    """With the bundled model (MODEL_CARD.md) the demo reconstructs both samples, writes every output,
    prints the synthetic clip's errors, and the real frames' focal length: the model card's figure."""
    r = run_cli("demo", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "bundled model d4rt-tiny" in r.stdout and "no trained model" not in r.stdout
    for sample in ("synthetic", "tum"):
        for name in OUTPUTS:
            assert (tmp_path / "d4rt-demo" / sample / name).exists(), (sample, name)
    assert all(np.isfinite(value) for value in printed_errors(r.stdout).values()), r.stdout
    with np.load(tmp_path / "d4rt-demo" / "tum" / "reconstruction.npz") as npz:
        assert npz["video_intrinsics"].shape == (17, 3, 3)
    # The printed focal length is the paper's per-frame recipe, as the model card measures it.
    fx = float(re.search(r"real frames: focal length ([0-9.]+) px vs the published fx = 535.4 px", r.stdout).group(1))
    card = json.loads(CARD_FOCAL.read_text())["tum-fr3-long-office-household"]["estimated_fx"]
    assert fx == pytest.approx(card, abs=0.051)  # printed to 0.1 px
    assert "viewer.html" in r.stdout.strip().splitlines()[-1]  # where to look next


def test_demo_without_a_model_answers_with_the_oracle(tmp_path, capsys):
    """The demo's fallback when no model is installed: the exact oracle answers the synthetic clip, so the
    printed errors, computed from the written files against its ground truth, are those of an exact
    pipeline; the real frames are skipped."""
    demo.run_synthetic(None, tmp_path / "synthetic")
    demo.run_real(None, tmp_path / "tum")
    stdout = capsys.readouterr().out
    assert "real footage" in stdout and "skipped" in stdout and not (tmp_path / "tum").exists()
    for name in OUTPUTS:
        assert (tmp_path / "synthetic" / name).exists(), name
    errors = printed_errors(stdout)
    assert all(errors[name] < 1e-5 for name in ("AbsRel", "ATE", "focal length error", "L1")), errors
    assert "delta<1.25 100.0%" in stdout and "APD3D 100.0%" in stdout
    # The figures: an exact path lies on the truth; an exact depth map has no error.
    for name in ("trajectory.png", "depth.png"):
        with Image.open(tmp_path / "synthetic" / name) as image:
            assert image.size[0] > 600 and image.size[1] > 250, name


def test_demo_real_frames_with_a_model(tmp_path, capsys):
    """With a model (here random weights: the number is meaningless), the real TUM frames are
    reconstructed, written, and their focal length compared with the published one."""
    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny")).eval()
    demo.run_real(model, tmp_path / "tum", resolution=(12, 16), point_stride=80)
    with np.load(tmp_path / "tum" / "reconstruction.npz") as npz:
        assert npz["depth"].shape == (17, 12, 16) and npz["video_intrinsics"].shape == (17, 3, 3)
        fx = float(np.median(npz["video_intrinsics"][:, 0, 0]))
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert f"the files' shared camera: f = {fx:.1f} px" in line and "vs the published fx = 535.4 px" in line
