"""`d4rt generate` and `d4rt demo` end to end, through the real console entry point."""

import subprocess
import sys

import numpy as np

from d4rt.synthetic import load_clip, render_clip


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "d4rt", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=600)


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


def test_demo_runs_end_to_end(tmp_path):
    r = run_cli("demo", "--out", str(tmp_path / "demo"))
    assert r.returncode == 0, r.stderr
    for name in ("clip.npz", "rgb.mp4", "depth.mp4", "preview.png"):
        assert (tmp_path / "demo" / name).stat().st_size > 1000, name
    assert "oracle" in r.stdout and "depth" in r.stdout
    clip = load_clip(tmp_path / "demo" / "clip.npz")
    assert clip.num_frames == 24
