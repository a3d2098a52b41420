"""`d4rt reconstruct` end to end through the console entry point: a generated mp4, an image folder and the
bundled real TUM RGB-D frames give every output, and each output parses; every bad input gives one clear
line, exit status 2, no traceback, and no output folder.

The model is a random-weight tiny one saved with save_pretrained (tests/ship covers the bundled one): its
outputs are meaningless but must exist and parse (their geometry is checked on the oracle in tests/io).
"""

import json
import re
import subprocess
import sys
from importlib.resources import files
from pathlib import Path

import av
import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from d4rt.cli import main
from d4rt.config import D4RTConfig
from d4rt.geometry.transforms import similarity_times_pose
from d4rt.io.formats import FORMATS, rerun_available
from d4rt.io.video import write_video
from d4rt.model import D4RT
from d4rt.synthetic import render_clip
from subprocess_budget import budget

TUM = Path(str(files("d4rt") / "assets" / "tum-fr3-long-office-household" / "rgb"))


def run_cli(*args, timeout=budget(600)):
    """Through the real console entry point (a new interpreter)."""
    return subprocess.run([sys.executable, "-m", "d4rt", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture
def cli(capsys):
    """The same ``main`` in this process (no interpreter and torch start-up per call): (status, out, err)."""

    def call(*args):
        status = main([str(a) for a in args])
        captured = capsys.readouterr()
        return subprocess.CompletedProcess(args, status, captured.out, captured.err)

    return call


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    torch.manual_seed(0)
    return D4RT(D4RTConfig.preset("tiny")).save_pretrained(tmp_path_factory.mktemp("ckpt") / "tiny")


@pytest.fixture(scope="module")
def clip():
    return render_clip(2, 8, 24, 32, environment="room", num_objects=3, camera_motion="orbit")


def check_outputs(out: Path, t: int, h: int, w: int, depth_size: tuple[int, int], num_tracks: int):
    """Every output of `d4rt reconstruct` exists and parses, with the expected sizes."""
    with np.load(out / "reconstruction.npz") as npz:
        m = len(npz["points"])
        expected = {"depth": (t, *depth_size), "confidence": (t, *depth_size), "intrinsics": (t, 3, 3),
                    "video_intrinsics": (t, 3, 3), "cam_to_world": (t, 4, 4), "points": (m, 3),
                    "point_colors": (m, 3), "point_frames": (m,), "tracks": (num_tracks, t, 3),
                    "track_visibility": (num_tracks, t), "timestamps": (t,)}
        for key, shape in expected.items():
            assert npz[key].shape == shape, key
        assert np.isfinite(npz["cam_to_world"]).all() and m > 0
    scale = json.loads((out / "depth" / "depth_scale.json").read_text())["depth_scale"]
    assert scale > 0 and len(list((out / "depth").glob("*.png"))) == t
    assert Image.open(out / "depth" / "000000.png").size == depth_size[::-1]
    for video in ("depth.mp4", "tracks.mp4"):
        with av.open(str(out / video)) as container:
            assert sum(1 for _ in container.decode(video=0)) == t, video
    header = (out / "points.ply").read_bytes().split(b"end_header\n")[0].decode()
    assert "format binary_little_endian 1.0" in header and f"element vertex {m}\n" in header
    scene = trimesh.load(out / "scene.glb")
    assert {"points", "cameras"} <= set(scene.geometry)
    pycolmap = pytest.importorskip("pycolmap")
    model = pycolmap.Reconstruction(str(out / "colmap" / "sparse" / "0"))
    # Random weights: few or no tracks reproject consistently (the oracle's model is checked in tests/io).
    assert model.num_images() == t and model.num_points3D() <= m
    assert all(p.track.length() >= 2 for p in model.points3D.values())  # multi-view points only
    assert len(list((out / "colmap" / "images").glob("*.png"))) == t
    rows = [line.split() for line in (out / "trajectory_tum.txt").read_text().splitlines() if line[0] != "#"]
    assert len(rows) == t and all(len(r) == 8 for r in rows)
    assert (out / "reconstruction.rrd").is_file() == rerun_available()
    assert "d4rt-data" in (out / "viewer.html").read_text()
    assert not list(out.parent.glob(".*partial*"))


def test_mp4_every_output(tmp_path, clip, checkpoint):
    video = write_video(tmp_path / "in.mp4", clip.rgb, fps=12)
    r = run_cli("reconstruct", video, "-o", tmp_path / "out", "--checkpoint", checkpoint, "--tracks", "4")
    assert r.returncode == 0, r.stderr
    check_outputs(tmp_path / "out", 8, 24, 32, (24, 32), 16)
    for stage in ("decode", "encode", "query", "decoding queries", "write"):
        assert f"{stage}:" in r.stderr, stage  # progress bars
    assert "8 frames of 32x24" in r.stdout and "wrote" in r.stdout
    stamps = np.load(tmp_path / "out" / "reconstruction.npz")["timestamps"]
    np.testing.assert_allclose(stamps, np.arange(8) / 12, atol=1e-6)  # the video's clock


def test_image_folder_with_range_and_encoder_resolution(tmp_path, clip, checkpoint, cli):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, frame in enumerate(clip.rgb):
        Image.fromarray(frame).save(folder / f"frame{i}.png")
    r = cli("reconstruct", folder, "-o", tmp_path / "out", "--checkpoint", checkpoint, "--start", "1",
                "--stride", "2", "--resolution", "encoder", "--tracks", "3", "--outputs", "npz,depth,ply,tum")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["depth", "points.ply", "reconstruction.npz",
                                                                    "trajectory_tum.txt"]
    with np.load(tmp_path / "out" / "reconstruction.npz") as npz:
        assert npz["depth"].shape == (4, 55, 74) and npz["tracks"].shape == (9, 4, 3)  # 64x64 pixels at 4:3


def test_real_tum_frames_every_output_with_known_intrinsics(tmp_path, checkpoint, cli):
    fx, fy, cx, cy = 535.4, 539.2, 320.1, 247.6
    r = cli("reconstruct", TUM, "-o", tmp_path / "out", "--checkpoint", checkpoint, "--resolution", "32x24",
                "--point-stride", "40", "--tracks", "3", "--intrinsics", f"{fx},{fy},{cx},{cy}")
    assert r.returncode == 0, r.stderr
    check_outputs(tmp_path / "out", 17, 480, 640, (24, 32), 9)
    with np.load(tmp_path / "out" / "reconstruction.npz") as npz:
        np.testing.assert_allclose(npz["video_intrinsics"][5], [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
        # The same camera for the 32x24 depth maps: sizes scale by 1/20, pixel centres stay centres.
        np.testing.assert_allclose(npz["intrinsics"][5], [[fx / 20, 0, (cx + 0.5) / 20 - 0.5],
                                                          [0, fy / 20, (cy + 0.5) / 20 - 0.5], [0, 0, 1]])
        assert npz["timestamps"][0] == pytest.approx(1341847980.722988)  # the file names are capture times


def test_long_video_windows_under_bf16(tmp_path, clip, checkpoint, cli):
    """More frames than one window: windows encoded one by one and stitched, under bf16 autocast."""
    video = tmp_path / "v.npy"
    np.save(video, clip.rgb)
    r = cli("reconstruct", video, "-o", tmp_path / "out", "--checkpoint", checkpoint, "--max-frames", "7",
            "--window", "4", "--overlap", "2", "--bf16", "--tracks", "2", "--outputs",
            "npz,tum,dense-tracks,motion-masks", "--dense-resolution", "8x6", "--motion-resolution", "8x6")
    assert r.returncode == 0 and "under bf16 autocast" in r.stdout, r.stderr
    # Windows [0, 4), [2, 6), [3, 7); the source keeps one encoded window, so recipes that go back to a
    # window encode it again.
    assert int(re.findall(r"encode: (\d+) window encodings", r.stderr)[-1]) >= 3
    with np.load(tmp_path / "out" / "reconstruction.npz") as npz:
        assert npz["depth"].shape == (7, 24, 32) and np.isfinite(npz["cam_to_world"]).all()
        np.testing.assert_allclose(npz["cam_to_world"][0], np.eye(4), atol=1e-9)
        assert not any(key.startswith("dense") for key in npz)
    with np.load(tmp_path / "out" / "dense_tracks.npz") as dense:  # tracked across the three windows
        n = len(dense["sources"])
        assert dense["points_world"].shape == (n, 7, 3) and tuple(dense["resolution"]) == (6, 8)
        assert float(dense["coverage"]) == 1.0 and 0 < int(dense["num_queries"]) < int(dense["naive_num_queries"])
    with np.load(tmp_path / "out" / "motion" / "motion.npz") as motion:  # each frame compared within its window
        # (untrained weights: where they answer a depth <= 0 there is no surface, NaN, and never "moving")
        rel, dynamic = motion["relative_motion"], motion["dynamic"]
        assert dynamic.shape == rel.shape == (7, 6, 8) and np.isfinite(rel).any()
        assert (dynamic == (np.nan_to_num(rel) > 0.05)).all()
        assert motion["target_frames"].tolist() == [[0, 1, 2, 3]] * 4 + [[2, 3, 4, 5]] * 2 + [[3, 4, 5, 6]]


def _make_bad_inputs(d: Path, clip):
    empty = d / "empty.mp4"
    empty.write_bytes(b"")
    corrupt = d / "corrupt.mp4"
    corrupt.write_bytes(b"\x00\x00\x00\x18ftypmp42 then garbage" * 20)
    text = d / "notes.doc"
    text.write_text("hello")
    listing = d / "notes.txt"  # a .txt input is a list of videos (many inputs): each line must exist
    listing.write_text("hello")
    no_images = d / "no_images"
    no_images.mkdir()
    (no_images / "readme.md").write_text("nothing here")
    mixed = d / "mixed"
    mixed.mkdir()
    Image.fromarray(clip.rgb[0]).save(mixed / "0.png")
    Image.fromarray(clip.rgb[1, :, :16]).save(mixed / "1.png")
    one = d / "one.npy"
    np.save(one, clip.rgb[:1])
    return {
        "missing": (d / "nope.mp4", "does not exist"),
        "empty": (empty, "is empty"),
        "corrupt": (corrupt, "cannot decode video"),
        "unsupported": (text, "unsupported input type '.doc'"),
        "list of missing videos": (listing, "notes.txt line 1: "),
        "no images": (no_images, "no images"),
        "mixed sizes": (mixed, "mixed sizes"),
        "too few frames": (one, "at least 2 are needed"),
    }


@pytest.mark.parametrize("case", ["missing", "empty", "corrupt", "unsupported", "list of missing videos", "no images",
                                  "mixed sizes", "too few frames"])
def test_bad_inputs_one_line_and_nothing_written(tmp_path, clip, checkpoint, cli, case):
    path, message = _make_bad_inputs(tmp_path, clip)[case]
    out = tmp_path / "results" / "run"
    call = run_cli if case == "corrupt" else cli  # one of them through the console entry point
    r = call("reconstruct", path, "-o", out, "--checkpoint", checkpoint)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("d4rt reconstruct: error: ") and message in lines[0], r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "results").exists()


def test_checkpoint_errors(tmp_path, clip, checkpoint, cli, monkeypatch):
    video = tmp_path / "v.npy"
    np.save(video, clip.rgb)
    # No --checkpoint in an installation without the bundled model (tests/ship checks the one that ships).
    monkeypatch.setattr("d4rt.model.weights.bundled_model_dir", lambda: tmp_path / "no-bundled-model")
    r = cli("reconstruct", video, "-o", tmp_path / "out")
    assert r.returncode == 2 and "pass --checkpoint DIR" in r.stderr and "d4rt demo" in r.stderr
    mismatched = tmp_path / "mismatched"
    mismatched.mkdir()
    (mismatched / "model.safetensors").write_bytes((checkpoint / "model.safetensors").read_bytes())
    config = json.loads((checkpoint / "config.json").read_text())
    config["decoder_depth"] = config["decoder_depth"] + 1
    (mismatched / "config.json").write_text(json.dumps(config))
    for ckpt, message in ((mismatched, "missing"), (tmp_path / "absent", "absent")):
        r = cli("reconstruct", video, "-o", tmp_path / "out", "--checkpoint", ckpt)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and message in lines[0] and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


def test_bad_options_and_debug(tmp_path, clip, cli):
    video = tmp_path / "v.npy"
    np.save(video, clip.rgb)
    for option, message in ((["--intrinsics", "500,500,320"], "--intrinsics must be four numbers"),
                            (["--intrinsics", "0,500,320,240"], "positive focal lengths"),
                            (["--resolution", "big"], "--resolution must be"),
                            (["--outputs", "ply,obj"], "unknown output format"),
                            (["--stride", "0"], "stride must be >= 1"),
                            (["--threads", "0"], "--threads must be >= 1"),
                            (["--motion-threshold", "0"], "motion threshold must be a finite number > 0"),
                            (["--chunk-size", "0"], "--chunk-size must be >= 1"),
                            (["--motion-resolution", "tiny"], "--motion-resolution must be"),
                            (["--device", "cuda:7"] if not torch.cuda.is_available() else ["--device", "nonsense"],
                             "--device")):
        r = cli("reconstruct", video, "-o", tmp_path / "out", *option)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and message in lines[0], (option, r.stderr)
    r = cli("reconstruct", tmp_path / "missing.mp4", "-o", tmp_path / "out", "--debug")
    assert r.returncode == 2 and "Traceback" in r.stderr and r.stderr.strip().endswith("does not exist")
    assert not (tmp_path / "out").exists()


def test_known_poses_and_scale(tmp_path, clip, checkpoint, cli):
    """--known-poses carries every file into the given poses' world (here the model's own estimate moved and scaled
    by a Sim(3), so the fit is exact), --scale multiplies lengths; their refusals are one line each."""
    video = tmp_path / "v.npy"
    np.save(video, clip.rgb)
    # fp32: the checks below compare runs with different decoder batches, which bf16 on an AMX CPU answers with other
    # kernels (differences of bf16's size, up to 7e-4 here), while what is tested is the scale and the known-pose fit.
    base = ("reconstruct", video, "--checkpoint", checkpoint, "--tracks", "2", "--outputs", "npz", "--dtype", "fp32")
    assert cli(*base, "-o", tmp_path / "plain").returncode == 0
    with np.load(tmp_path / "plain" / "reconstruction.npz") as npz:
        estimated, depth = npz["cam_to_world"], npz["depth"]
    sim = np.diag([3.0, 3.0, 3.0, 1.0])
    sim[:3, 3] = [1.0, 2.0, 3.0]
    known = np.stack([similarity_times_pose(sim, pose) for pose in estimated])
    np.save(tmp_path / "poses.npy", known)
    r = cli(*base, "-o", tmp_path / "known", "--known-poses", tmp_path / "poses.npy")
    assert r.returncode == 0 and "carried into the known poses' world: scale 3" in r.stderr, r.stderr
    with np.load(tmp_path / "known" / "reconstruction.npz") as npz:
        np.testing.assert_allclose(npz["cam_to_world"], known, atol=1e-4)
        np.testing.assert_allclose(npz["depth"], 3.0 * depth, rtol=1e-4)
    r = cli(*base, "-o", tmp_path / "scaled", "--scale", "0.5", "--chunk-size", "7")  # small decoder batches
    assert r.returncode == 0, r.stderr
    with np.load(tmp_path / "scaled" / "reconstruction.npz") as npz:
        np.testing.assert_allclose(npz["depth"], 0.5 * depth, rtol=1e-5, atol=1e-6)  # atol: fp32 noise near 0
        np.testing.assert_allclose(npz["cam_to_world"][:, :3, 3], 0.5 * estimated[:, :3, 3], atol=1e-6)
    (tmp_path / "poses.txt").write_text("0 0 0 0 0 0 0 1\n")
    np.save(tmp_path / "few.npy", known[:3])
    for extra, message in ((("--scale", "-1"), "--scale must be a finite number > 0"),
                           (("--scale", "2", "--known-poses", tmp_path / "poses.npy"), "not both"),
                           (("--known-poses", tmp_path / "nowhere.npy"), "does not exist"),
                           (("--known-poses", tmp_path / "poses.txt"), "these frames have no clock"),
                           (("--known-poses", tmp_path / "few.npy"), "holds 3 poses but source frame 7 is used")):
        r = cli(*base, "-o", tmp_path / "refused", *extra)
        errors = [line for line in r.stderr.splitlines() if "error" in line]
        assert r.returncode == 2 and len(errors) == 1 and message in errors[0], (extra, r.stderr)
        assert not (tmp_path / "refused").exists()


def test_output_folder_and_confidence_refusals(tmp_path, clip, checkpoint, cli):
    """A non-empty output folder needs --overwrite (then it is replaced as a whole); a confidence threshold
    that leaves nothing is an error with the range found. Each: one line, exit 2, nothing written."""
    video = tmp_path / "v.npy"
    np.save(video, clip.rgb[:4])
    out = tmp_path / "out"
    out.mkdir()
    (out / "earlier.ply").write_text("an earlier run's")
    base = ("reconstruct", video, "-o", out, "--checkpoint", checkpoint, "--tracks", "2")
    for extra, message in (((), "is not empty: pass --overwrite"),
                           (("--overwrite", "--min-confidence", "1e9"), "confidence >= 1e+09 (this reconstruction's")):
        r = cli(*base, *extra)
        errors = [line for line in r.stderr.splitlines() if "error" in line]  # (after progress bars: work began)
        assert r.returncode == 2 and len(errors) == 1 and message in errors[0] and "Traceback" not in r.stderr, r.stderr
        assert [p.name for p in tmp_path.iterdir()] == ["v.npy", "out"] and [p.name for p in out.iterdir()] == ["earlier.ply"]
    r = cli(*base, "--overwrite", "--outputs", "npz,tum", "--dtype", "fp32")
    assert r.returncode == 0 and "autocast" not in r.stdout, r.stderr
    assert "outputs: depth maps 32x24, point cloud from the depth maps, 2x2 tracks: about" in r.stdout
    assert sorted(p.name for p in out.iterdir()) == ["reconstruction.npz", "trajectory_tum.txt"]


def test_a_video_with_a_shot_cut_is_written_shot_by_shot(tmp_path, clip, checkpoint, cli):
    other = render_clip(5, 4, 24, 32, environment="outdoor", num_objects=2, camera_motion="pan")
    video = tmp_path / "cut.npy"
    np.save(video, np.concatenate([clip.rgb[:5], other.rgb]))
    out = tmp_path / "out"
    r = cli("reconstruct", video, "-o", out, "--checkpoint", checkpoint, "--tracks", "2", "--outputs", "npz,tum")
    assert r.returncode == 0, r.stderr
    assert "shot cuts before frames 5: 2 shots" in r.stdout
    assert sorted(p.name for p in out.iterdir()) == ["shot_000", "shot_001", "shots.json"]
    summary = json.loads((out / "shots.json").read_text())
    assert summary["cuts_before_frames"] == [5]
    assert [s["frames"] for s in summary["shots"]] == [[0, 4], [5, 8]]
    for shot, frames in (("shot_000", 5), ("shot_001", 4)):
        with np.load(out / shot / "reconstruction.npz") as npz:
            assert npz["cam_to_world"].shape == (frames, 4, 4)
            np.testing.assert_allclose(npz["cam_to_world"][0], np.eye(4), atol=1e-9)  # each shot its own world
    # Stitched through on request: one folder, one camera path.
    r = cli("reconstruct", video, "-o", out, "--overwrite", "--no-cut-detection", "--checkpoint", checkpoint,
            "--tracks", "2", "--outputs", "tum")
    assert r.returncode == 0 and sorted(p.name for p in out.iterdir()) == ["trajectory_tum.txt"], r.stderr


def test_every_format_has_a_cli_name(capsys):
    with pytest.raises(SystemExit) as done:
        main(["reconstruct", "--help"])
    text = "".join(capsys.readouterr().out.split())  # the help wraps lines anywhere, even at hyphens
    assert done.value.code == 0 and all(name in text for name in FORMATS)


def test_default_output_size_is_the_inputs_up_to_vga_pixels(capsys):
    from d4rt.cli.reconstruct import default_resolution, parse_resolution
    from d4rt.errors import UserError

    assert parse_resolution("auto") == "auto" and parse_resolution("original") is None
    assert default_resolution(480, 640) is None and default_resolution(272, 640) is None
    assert capsys.readouterr().err == ""
    assert default_resolution(3000, 4000) == (480, 640)  # 12 megapixels -> VGA, same 4:3
    assert "outputs at 640x480, not the input's 4000x3000" in capsys.readouterr().err
    h, w = default_resolution(1080, 2538)  # 2.35:1 keeps its shape
    assert abs(w / h - 2538 / 1080) < 0.01 and h * w <= 1.01 * 640 * 480
    with pytest.raises(UserError, match="'original', 'encoder' or WIDTHxHEIGHT"):
        parse_resolution("auto", "--dense-resolution")
