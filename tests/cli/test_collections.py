"""`d4rt reconstruct` over many videos: sharded across 2 torchrun processes it writes exactly what one
process writes, each input once, with a summary; a killed run resumes with only the rest; a corrupt video
is recorded as failed and never stops the others.

The model is the bundled one (a random-weight model's depths can all be negative, which fails every
video: these tests need videos that succeed).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from d4rt.cli import main
from d4rt.cli.collection import SUMMARY, expand_inputs, is_collection, output_names
from d4rt.errors import UserError
from d4rt.io.video import write_video
from d4rt.model.weights import bundled_model_dir
from d4rt.synthetic import render_clip
from subprocess_budget import budget

NUM_VIDEOS = 6
# Small, fast outputs: the arrays compared are those of reconstruction.npz and the TUM trajectory.
OPTIONS = ["--outputs", "npz,tum", "--tracks", "3", "--resolution", "encoder", "--dtype", "fp32", "--no-progress"]


@pytest.fixture(scope="module")
def checkpoint() -> Path:
    return bundled_model_dir()


@pytest.fixture(scope="module")
def videos(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("videos")
    for i in range(NUM_VIDEOS):
        write_video(folder / f"clip{i}.mp4", render_clip(i, 5, 36, 48, num_objects=1).rgb, fps=10)
    return folder


@pytest.fixture(scope="module")
def sequential(tmp_path_factory, videos, checkpoint) -> Path:
    """One process over every video: the reference (a process of its own, one thread like every run compared
    with it: float sums depend on the thread count)."""
    out = tmp_path_factory.mktemp("sequential") / "out"
    run = subprocess.run(command(videos, "-o", out, "--checkpoint", checkpoint), capture_output=True, text=True,
                         env=environment(), timeout=budget(300))
    assert run.returncode == 0, run.stderr[-3000:]
    return out


def command(*args) -> list[str]:
    return [sys.executable, "-m", "d4rt", "reconstruct", *map(str, args), *OPTIONS]


def environment() -> dict:
    return {**os.environ, "OMP_NUM_THREADS": "1"}


def summary(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / SUMMARY).read_text().splitlines()]


def assert_same_outputs(a: Path, b: Path, names) -> None:
    for name in names:
        x, y = np.load(a / name / "reconstruction.npz"), np.load(b / name / "reconstruction.npz")
        assert sorted(x.files) == sorted(y.files)
        for key in x.files:
            assert np.array_equal(x[key], y[key], equal_nan=x[key].dtype.kind == "f"), (name, key)
        assert (a / name / "trajectory_tum.txt").read_text() == (b / name / "trajectory_tum.txt").read_text()


@pytest.mark.slow(seconds=31)
def test_two_torchrun_processes_write_what_one_process_writes(tmp_path, videos, checkpoint, sequential):
    out = tmp_path / "out"
    launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2", "-m", "d4rt"]
    run = subprocess.run(launcher + command(videos, "-o", out, "--checkpoint", checkpoint)[3:], capture_output=True,
                         text=True, env=environment(), timeout=budget(300))
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    rows = summary(out)
    names = [f"clip{i}" for i in range(NUM_VIDEOS)]
    assert [Path(r["input"]).name for r in rows] == [f"{n}.mp4" for n in names]  # each input once, in order
    assert {r["status"] for r in rows} == {"done"} and all(r["frames"] == 5 for r in rows)
    assert sorted(p.name for p in out.iterdir()) == sorted(names + [SUMMARY])  # no rank files left
    assert_same_outputs(out, sequential, names)
    # Each rank took its own share: both logged videos of their own.
    assert run.stdout.count("wrote ") == NUM_VIDEOS


@pytest.mark.slow(seconds=33)
def test_a_killed_run_resumes_with_only_the_rest(tmp_path, videos, checkpoint, sequential):
    out = tmp_path / "out"
    process = subprocess.Popen(command(videos, "-o", out, "--checkpoint", checkpoint), stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, env=environment(), start_new_session=True)
    deadline = time.monotonic() + budget(300)
    try:
        while sum(p.is_dir() and not p.name.startswith(".") for p in out.glob("*")) < 2:
            assert process.poll() is None, "the run ended before it could be killed"
            assert time.monotonic() < deadline, "no output appeared"
            time.sleep(0.05)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    finished = {p.name for p in out.iterdir() if p.is_dir() and not p.name.startswith(".")}
    assert 2 <= len(finished) < NUM_VIDEOS and not (out / SUMMARY).exists()

    rerun = subprocess.run(command(videos, "-o", out, "--checkpoint", checkpoint), capture_output=True, text=True,
                           env=environment(), timeout=budget(300))
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    rows = summary(out)
    assert len(rows) == NUM_VIDEOS
    done = {Path(r["output"]).name for r in rows if r["status"] == "done"}
    complete = {Path(r["output"]).name for r in rows if r["status"] == "complete"}
    assert complete == finished and len(done) == NUM_VIDEOS - len(finished)  # only the rest ran
    assert_same_outputs(out, sequential, [f"clip{i}" for i in range(NUM_VIDEOS)])


def test_a_corrupt_video_is_recorded_and_the_others_are_done(tmp_path, videos, checkpoint, capsys):
    (tmp_path / "broken.mp4").write_bytes(b"this is not a video" * 20)  # exists, but cannot be decoded
    listing = tmp_path / "videos.txt"
    listing.write_text(f"# two good, one broken\n{videos / 'clip0.mp4'}\nbroken.mp4\n{videos / 'clip1.mp4'}\n")
    out = tmp_path / "out"
    args = ["reconstruct", str(listing), "-o", str(out), "--checkpoint", str(checkpoint), *OPTIONS]
    assert main(args) == 1  # some input failed: the status says so, the summary says which
    rows = summary(out)
    assert [r["status"] for r in rows] == ["done", "failed", "done"]
    assert "broken.mp4" in rows[1]["error"] and "\n" not in rows[1]["error"]
    assert sorted(p.name for p in out.iterdir()) == ["clip0", "clip1", SUMMARY]
    capsys.readouterr()
    # A re-run leaves the failure recorded without trying it again, unless asked to.
    main(args)
    assert [r["status"] for r in summary(out)] == ["complete", "failed", "complete"]
    assert "broken.mp4: failed" not in capsys.readouterr().out
    main(args + ["--retry-failed"])
    assert "broken.mp4: failed" in capsys.readouterr().out


def test_inputs_are_expanded_and_named_once(tmp_path, videos):
    assert not is_collection([str(videos / "clip0.mp4")])
    assert is_collection([str(videos)]) and is_collection([str(videos / "clip*.mp4")])
    images = tmp_path / "frames"
    images.mkdir()
    (images / "0.png").write_bytes(b"")
    assert not is_collection([str(images)])  # a folder of images is one video
    found = expand_inputs([str(videos / "clip*.mp4"), str(videos / "clip0.mp4")])
    assert [p.name for p in found] == [f"clip{i}.mp4" for i in range(NUM_VIDEOS)]  # each once, in order
    assert output_names([Path("a/x.mp4"), Path("b/x.mp4"), Path("c/y.mov"), Path("frames")]) == ["x", "x_2", "y",
                                                                                                 "frames"]
    with pytest.raises(UserError, match="no file matches"):
        expand_inputs([str(tmp_path / "none*.mp4")])
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(UserError, match="lists no input"):
        expand_inputs([str(tmp_path / "empty.txt")])
