"""Each reader on a tiny fixture written in its dataset's published on-disk layout.

The fixtures are written here from the formats' specifications (byte layouts, units, file names), not
with the readers' own code, and every test checks shapes, units and conventions: depth in metres (or
Sintel units), intrinsics in pixels, poses camera-to-world.
"""

import io

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from d4rt.errors import UserError
from d4rt.evaluation.readers import detect_format, list_sequences, read_sequence
from d4rt.geometry.camera import project
from d4rt.geometry.transforms import apply_transform, invert_rigid
from d4rt.synthetic import render_clip
from tests.evaluation.layouts import H, RNG, W, random_poses, random_rgb, write_png, write_re10k, write_sintel


# ------------------------------------------------------------------------------------------ Sintel
def test_sintel(tmp_path):
    depths, k, cam_to_world = write_sintel(tmp_path, "alley_2", 3)
    write_sintel(tmp_path, "temple_3", 2)
    assert detect_format(tmp_path) == "sintel"
    assert list_sequences("sintel", tmp_path) == ["alley_2", "temple_3"]
    seq = read_sequence("sintel", tmp_path, "alley_2")
    assert seq.rgb.shape == (3, H, W, 3) and seq.rgb.dtype == np.uint8
    assert np.array_equal(seq.depth, depths)
    assert np.allclose(seq.intrinsics, k) and np.allclose(seq.cam_to_world, cam_to_world)
    assert seq.frame_names == ["frame_0001", "frame_0002", "frame_0003"]
    assert read_sequence("sintel", tmp_path, "alley_2", frames=slice(1, None)).num_frames == 2
    # Convention check: a world point seen in frame 0 at pixel (x, y), depth d, lands where the
    # extrinsics N = [R | t] say in frame 1 (x1 ~ M (R X + t)).
    world_to_cam = invert_rigid(cam_to_world)
    point = apply_transform(seq.cam_to_world[0], np.array([0.3, -0.2, 4.0]))
    expected = k @ (world_to_cam[1, :3, :3] @ point + world_to_cam[1, :3, 3])
    xy, _ = project(apply_transform(invert_rigid(seq.cam_to_world[1]), point), seq.intrinsics[1])
    assert np.allclose(xy, expected[:2] / expected[2])


def test_sintel_rejects_a_foreign_file(tmp_path):
    write_sintel(tmp_path, "alley_2", 1)
    (tmp_path / "training/depth/alley_2/frame_0001.dpt").write_bytes(b"\0" * 40)
    with pytest.raises(UserError, match="not a Sintel .dpt"):
        read_sequence("sintel", tmp_path, "alley_2")


# ------------------------------------------------------------------------------------------ Bonn
def test_bonn(tmp_path):
    base = tmp_path / "rgbd_bonn_balloon2"
    stamps = 1548266469.0 + 0.033 * np.arange(5)
    depth_m = RNG.uniform(0.5, 5, (5, H, W))
    depth_m[:, 0, 0] = 0.0
    for i, ts in enumerate(stamps):
        write_png(base / "rgb" / f"{ts:.6f}.png", random_rgb())
        write_png(base / "depth" / f"{ts + 0.001:.6f}.png", np.round(depth_m[i] * 5000).astype(np.uint16))
    # Ground truth at 100 Hz-ish, offset by 4 ms: frame i takes the nearest line.
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for i, ts in enumerate(stamps):
        q = Rotation.from_rotvec([0, 0, 0.1 * i]).as_quat()  # scipy: (x, y, z, w)
        lines.append(f"{ts + 0.004:.6f} {i} {2 * i} 0.5 " + " ".join(f"{v:.9f}" for v in q))
    (base / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    assert detect_format(tmp_path) == "bonn"
    assert list_sequences("bonn", tmp_path) == ["balloon2"]
    seq = read_sequence("bonn", tmp_path, "balloon2", frames=slice(1, 4))
    assert seq.num_frames == 3 and seq.rgb.shape == (3, H, W, 3)
    assert np.allclose(seq.depth, np.round(depth_m[1:4] * 5000) / 5000, atol=1e-6)  # metres
    assert seq.depth[0, 0, 0] == 0.0
    assert np.allclose(seq.intrinsics[0], [[542.822841, 0, 315.593520], [0, 542.576870, 237.756098], [0, 0, 1]])
    assert np.allclose(seq.cam_to_world[:, :3, 3], [[1, 2, 0.5], [2, 4, 0.5], [3, 6, 0.5]])
    assert np.allclose(seq.cam_to_world[2, :3, :3], Rotation.from_rotvec([0, 0, 0.3]).as_matrix())


# ------------------------------------------------------------------------------------------ KITTI
def test_kitti_official_and_gathered_layouts(tmp_path):
    base = tmp_path / "depth_selection" / "val_selection_cropped"
    drive = "2011_09_26_drive_0002_sync"
    depth_m = RNG.uniform(1, 80, (3, H, W))
    depth_m[:, ::2] = 0.0  # sparse LiDAR
    k = np.array([[721.5377, 0, 596.5593], [0, 721.5377, 149.854], [0, 0, 1]])
    for i, frame in enumerate((5, 15, 10)):  # written out of order: the reader sorts by frame number
        name = f"{drive}_image_{frame:010d}_image_02"
        write_png(base / "image" / f"{name}.png", random_rgb())
        write_png(base / "groundtruth_depth" / f"{drive}_groundtruth_depth_{frame:010d}_image_02.png",
                  np.round(depth_m[i] * 256).astype(np.uint16))
        (base / "intrinsics").mkdir(exist_ok=True)
        (base / "intrinsics" / f"{name}.txt").write_text(" ".join(f"{v:.4f}" for v in k.ravel()))
    assert detect_format(tmp_path) == "kitti"
    assert list_sequences("kitti", tmp_path) == [f"{drive}_02"]
    seq = read_sequence("kitti", tmp_path, f"{drive}_02")
    assert seq.frame_names[0].endswith("0000000005_image_02") and seq.frame_names[1].endswith("10_image_02")
    order = [0, 2, 1]  # frames 5, 10, 15
    assert np.allclose(seq.depth, np.round(depth_m[order] * 256) / 256, atol=1e-6)
    assert np.allclose(seq.intrinsics, k, atol=1e-4)
    # MonST3R's gathered layout: per-sequence folders, no intrinsics.
    gathered = tmp_path / "gathered"
    for i in range(2):
        write_png(gathered / "image_gathered" / f"{drive}_02" / f"{i:010d}.png", random_rgb())
        write_png(gathered / "groundtruth_depth_gathered" / f"{drive}_02" / f"{i:010d}.png",
                  np.round(depth_m[i] * 256).astype(np.uint16))
    seq = read_sequence("kitti", gathered, f"{drive}_02")
    assert seq.depth.shape == (2, H, W) and seq.intrinsics is None
    assert np.allclose(seq.depth, np.round(depth_m[:2] * 256) / 256, atol=1e-6)


# ------------------------------------------------------------------------------------------ ScanNet
def test_scannet(tmp_path):
    base = tmp_path / "scene0707_00"
    poses = random_poses(7)
    poses[4] = -np.inf  # ScanNet marks lost tracking with -inf
    depth_mm = RNG.integers(0, 8000, (7, H, W)).astype(np.uint16)
    for i in range(7):
        write_png(base / "color" / f"{i}.jpg", random_rgb(2 * H, 2 * W))  # colour at twice the depth size
        write_png(base / "depth" / f"{i}.png", depth_mm[i])
        (base / "pose").mkdir(exist_ok=True)
        np.savetxt(base / "pose" / f"{i}.txt", poses[i])
    k = np.array([[577.59, 0, 318.9, 0], [0, 578.73, 242.68, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    (base / "intrinsic").mkdir()
    np.savetxt(base / "intrinsic" / "intrinsic_depth.txt", k)
    assert detect_format(tmp_path) == "scannet"
    seq = read_sequence("scannet", tmp_path, "scene0707_00", stride=2, max_frames=3)  # frames 0, 2, 4
    assert seq.frame_names == ["0", "2"] and "[4]" in seq.notes[0]  # frame 4 has no pose
    assert seq.rgb.shape == (2, H, W, 3)  # resized to the depth resolution
    assert np.allclose(seq.depth, depth_mm[[0, 2]] / 1000.0)
    assert np.allclose(seq.cam_to_world, poses[[0, 2]]) and np.allclose(seq.intrinsics[0], k[:3, :3])


# ------------------------------------------------------------------------------------------ TAPVid-3D
def jpeg(array):
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, format="JPEG", quality=95)
    return buffer.getvalue()


@pytest.mark.parametrize("frames_as", ["bytes", "object", "video"])
def test_tapvid3d(tmp_path, frames_as):
    t, n = 4, 6
    tracks = np.concatenate([RNG.uniform(-1, 1, (t, n, 2)), RNG.uniform(2, 8, (t, n, 1))], -1)
    visibility = RNG.uniform(size=(t, n)) > 0.3
    fx_fy_cx_cy = np.array([20.0, 21.0, (W - 1) / 2, (H - 1) / 2])
    query_t = RNG.integers(0, t, n)
    # Query pixels: the tracked point projected in its query frame (as tapnet's annotations are made).
    k = np.array([[20.0, 0, fx_fy_cx_cy[2]], [0, 21.0, fx_fy_cx_cy[3]], [0, 0, 1]])
    xy, _ = project(tracks[query_t, np.arange(n)], k)
    queries = np.concatenate([xy, query_t[:, None]], 1)
    ramp = np.linspace(0, 1, W)[None, :, None] * np.linspace(0.5, 1, H)[:, None, None]
    frames = np.stack([(255 * ramp * [1.0, 0.5, 0.2 + 0.2 * i]).astype(np.uint8) for i in range(t)])
    arrays = dict(tracks_XYZ=tracks.astype(np.float32), visibility=visibility, queries_xyt=queries,
                  fx_fy_cx_cy=fx_fy_cx_cy)
    if frames_as == "video":
        arrays["video"] = frames
    else:
        encoded = [jpeg(f) for f in frames]
        arrays["images_jpeg_bytes"] = np.array(encoded, dtype=object if frames_as == "object" else None)
    (tmp_path / "drivetrack").mkdir()
    np.savez(tmp_path / "drivetrack" / "segment_1.npz", **arrays)
    assert detect_format(tmp_path) == "tapvid3d"
    assert list_sequences("tapvid3d", tmp_path) == ["drivetrack/segment_1"]
    seq = read_sequence("tapvid3d", tmp_path, "drivetrack/segment_1")
    assert seq.rgb.shape == (t, H, W, 3)
    if frames_as == "video":
        assert np.array_equal(seq.rgb, frames)
    else:
        assert np.abs(seq.rgb.astype(int) - frames).mean() < 3  # JPEG round trip
    assert np.allclose(seq.tracks.points, tracks.astype(np.float32)) and seq.tracks.points.shape == (t, n, 3)
    assert np.array_equal(seq.tracks.visible, visibility)
    assert np.array_equal(seq.tracks.query_frames, query_t) and np.allclose(seq.tracks.query_xy, xy)
    assert np.allclose(seq.intrinsics[0], k)
    # The query pixel is where the track's point projects in its query frame (pixels, camera frame).
    proj, _ = project(seq.tracks.points[seq.tracks.query_frames, np.arange(n)], seq.intrinsics[0])
    assert np.allclose(proj, seq.tracks.query_xy, atol=1e-4)


# ------------------------------------------------------------------------------------------ synthetic
def test_synthetic_clips_with_oracle_tracks(tmp_path):
    clip = render_clip(5, 4, 24, 32, camera_motion="orbit", num_objects=3)
    clip.save(tmp_path / "clip_0.npz")
    assert detect_format(tmp_path) == "synthetic"
    seq = read_sequence("synthetic", tmp_path, "clip_0", num_tracks=20)
    assert np.array_equal(seq.depth, clip.depth) and np.allclose(seq.cam_to_world, clip.cam_to_world)
    tracks = seq.tracks
    assert tracks.points.shape == (4, 20, 3) and tracks.visible.shape == (4, 20)
    n = np.arange(20)
    assert tracks.visible[tracks.query_frames, n].all()
    # In its query frame a track sits at the query pixel's centre, at the rendered depth.
    xy, z = project(tracks.points[tracks.query_frames, n], seq.intrinsics[tracks.query_frames])
    assert np.allclose(xy, tracks.query_xy, atol=1e-6)
    rows, cols = tracks.query_xy[:, 1].astype(int), tracks.query_xy[:, 0].astype(int)
    assert np.allclose(z, clip.depth[tracks.query_frames, rows, cols], rtol=1e-5)
    # Same seed, same tracks.
    again = read_sequence("synthetic", tmp_path, "clip_0", num_tracks=20)
    assert np.array_equal(again.tracks.points, tracks.points)


def test_unknown_layouts_and_formats(tmp_path):
    with pytest.raises(UserError, match="cannot tell the dataset format"):
        detect_format(tmp_path)
    with pytest.raises(UserError, match="unknown dataset format"):
        list_sequences("nyu", tmp_path)
    with pytest.raises(UserError, match="not found"):
        list_sequences("sintel", tmp_path / "missing")


def test_re10k(tmp_path):
    root = tmp_path / "RealEstate10K" / "test"
    stamps, k, cam_to_world = write_re10k(root, "0a1b2c", 30)
    write_re10k(root, "ffee00", 3)
    (root / "ffee00" / f"{1_000_000 + 33_367 * 2}.png").unlink()  # a frame not extracted
    assert detect_format(tmp_path / "RealEstate10K") == "re10k"
    assert list_sequences("re10k", tmp_path / "RealEstate10K") == ["0a1b2c", "ffee00"]
    seq = read_sequence("re10k", root, "0a1b2c")
    assert seq.depth is None and seq.num_frames == 30 and seq.frame_names[0] == str(stamps[0])
    np.testing.assert_allclose(seq.intrinsics, np.broadcast_to(k, (30, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(seq.cam_to_world, cam_to_world, atol=1e-9)
    thinned = read_sequence("re10k", root, "0a1b2c", max_frames=24)  # evenly, first and last kept
    assert thinned.num_frames == 24 and thinned.frame_names[0] == str(stamps[0])
    assert thinned.frame_names[-1] == str(stamps[-1])
    short = read_sequence("re10k", root, "ffee00")
    assert short.num_frames == 2 and short.notes == ["skipped 1 camera lines without an extracted frame"]
    (root / "bad.txt").write_text("url\n1 2 3\n")
    (root / "bad").mkdir()
    with pytest.raises(UserError, match="need 19 numbers"):
        read_sequence("re10k", root, "bad")
    (root / "nofolder.txt").write_text((root / "ffee00.txt").read_text())
    with pytest.raises(UserError, match="no folder of extracted frames"):
        read_sequence("re10k", root, "nofolder")
    odd = root / "0a1b2c" / f"{stamps[1]}.png"
    write_png(odd, random_rgb(H + 2, W))
    with pytest.raises(UserError, match=f"frame {odd.name} is {W}x{H + 2}"):
        read_sequence("re10k", root, "0a1b2c")
