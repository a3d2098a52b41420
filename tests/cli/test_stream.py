"""`d4rt stream`: frames pushed one at a time give the cameras and depth maps of the offline window recipe
on the same frames (in process exactly; through a pipe within 1e-5), the files stay consistent when the
stream is stopped, and bad streams get one line.

The model is the bundled one in float32 on the CPU (windows of 6 frames with an overlap of 2, so a short
clip has several windows and a last one that starts inside the one before, as offline).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from d4rt.model import D4RT
from d4rt.reconstruction import Reconstruction
from d4rt.reconstruction.streaming import StreamingReconstruction
from d4rt.synthetic import render_clip
from subprocess_budget import budget

WINDOW, OVERLAP = 6, 2


@pytest.fixture(scope="module")
def model():
    return D4RT.from_pretrained()


@pytest.fixture(scope="module")
def clip():
    return render_clip(3, 15, 36, 48, num_objects=2, camera_motion="orbit")


def offline(model, rgb, depth_size=(9, 12), pose_pairs=None):
    rec = Reconstruction.from_model(model, rgb, window=WINDOW, overlap=OVERLAP, pose_pairs=pose_pairs, progress=False)
    return rec.cameras(), rec.depth(depth_size), rec.windows


def stream_command(out, *extra) -> list[str]:
    return [sys.executable, "-m", "d4rt", "stream", "-", "--size", "48x36", "-o", str(out), "--window", str(WINDOW),
            "--overlap", str(OVERLAP), "--dtype", "fp32", *map(str, extra)]


# A shifted last window, windows that tile, one short window; the model's own camera pairs (the shipped model
# chains adjacent frames) and the paper's (every frame against its window's first).
@pytest.mark.parametrize("length, pose_pairs", [(15, None), (14, None), (5, None), (15, "first"), (15, "graph")])
def test_pushing_frames_one_at_a_time_equals_the_offline_recipe(model, clip, length, pose_pairs):
    rgb = clip.rgb[:length]
    cams, depth, windows = offline(model, rgb, pose_pairs=pose_pairs)
    stream = StreamingReconstruction.from_model(model, window=WINDOW, overlap=OVERLAP, depth_size=(9, 12),
                                                pose_pairs=pose_pairs)
    results = [r for frame in rgb for r in stream.push(frame)] + stream.finish()
    assert [r.window for r in results] == windows
    assert np.concatenate([r.frames for r in results]).tolist() == list(range(length))  # every frame once
    assert np.array_equal(np.concatenate([r.cam_to_world for r in results]), cams.cam_to_world)
    assert np.array_equal(np.concatenate([r.intrinsics for r in results]), cams.intrinsics)
    assert np.array_equal(np.concatenate([r.depth for r in results]), depth.depth)
    # Bounded memory: frames of at most one window are held, plus the last full window's.
    assert len(stream.frames) < WINDOW


def test_frames_piped_to_d4rt_stream_give_the_offline_cameras(tmp_path, model, clip):
    out = tmp_path / "out"
    run = subprocess.run(stream_command(out, "--depth-resolution", "12x9"), input=clip.rgb.tobytes(),
                         capture_output=True, timeout=budget(300), env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert run.returncode == 0, run.stderr.decode()[-3000:]
    cams, depth, windows = offline(model, clip.rgb)
    parts = [np.load(out / f"window_{k:03d}.npz") for k in range(len(windows))]
    assert not (out / f"window_{len(windows):03d}.npz").exists()
    assert [tuple(p["window"]) for p in parts] == windows
    np.testing.assert_allclose(np.concatenate([p["cam_to_world"] for p in parts]), cams.cam_to_world, atol=1e-5)
    np.testing.assert_allclose(np.concatenate([p["intrinsics"] for p in parts]), cams.intrinsics, rtol=1e-5)
    np.testing.assert_allclose(np.concatenate([p["depth"] for p in parts]), depth.depth, rtol=1e-5, atol=1e-6)
    trajectory = [line for line in (out / "trajectory_tum.txt").read_text().splitlines() if not line.startswith("#")]
    assert len(trajectory) == len(clip.rgb)
    summary = json.loads((out / "stream.json").read_text())
    assert summary["frames"] == len(clip.rgb) and summary["windows"] == len(windows)
    assert len(summary["latency_s"]) == len(windows) and summary["stopped_by"] is None


def test_a_stopped_stream_leaves_consistent_files(tmp_path, clip):
    out = tmp_path / "out"
    process = subprocess.Popen(stream_command(out), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, env={**os.environ, "OMP_NUM_THREADS": "1"})
    process.stdin.write(clip.rgb[:8].tobytes())
    process.stdin.flush()
    deadline = time.monotonic() + budget(300)
    while not (out / "window_000.npz").exists():
        assert process.poll() is None and time.monotonic() < deadline, process.stderr.read().decode()[-2000:]
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    with contextlib.suppress(BrokenPipeError):  # the stream may have ended already (see below)
        process.stdin.write(clip.rgb[8:9].tobytes())  # the frame after the signal ends the loop
    with contextlib.suppress(BrokenPipeError):  # close closes the pipe even when its flush fails
        process.stdin.close()
    assert process.wait(timeout=budget(300)) == 0, process.stderr.read().decode()[-2000:]
    summary = json.loads((out / "stream.json").read_text())
    # The signal may land while the sixth frame's window is still being handled (the stream then ends after
    # it) or while a later frame is awaited (it ends after the frame that arrives next): 6 to 9 frames.
    assert summary["stopped_by"] == "SIGTERM" and 6 <= summary["frames"] <= 9
    frames = np.concatenate([np.load(out / f"window_{k:03d}.npz")["frames"] for k in range(summary["windows"])])
    assert frames.tolist() == list(range(summary["frames"]))  # every frame received is in exactly one window
    assert not list(out.glob(".*"))  # no temporary file left


def test_bad_streams_get_one_line(tmp_path, clip):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    partial = subprocess.run(stream_command(tmp_path / "a"), input=clip.rgb[:3].tobytes()[:-7], capture_output=True,
                             timeout=budget(300), env=env)
    assert partial.returncode == 2
    assert partial.stderr.decode().strip().splitlines()[-1].startswith("d4rt stream: error: the input ended inside")
    nothing = subprocess.run(stream_command(tmp_path / "b"), input=b"", capture_output=True, timeout=budget(300),
                             env=env)
    assert nothing.returncode == 2 and "gave no frames" in nothing.stderr.decode()
    no_size = subprocess.run([sys.executable, "-m", "d4rt", "stream", "-", "-o", str(tmp_path / "c")],
                             capture_output=True, timeout=budget(60), env=env)
    assert no_size.returncode == 2 and "need --size" in no_size.stderr.decode()
