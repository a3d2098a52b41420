"""Every export of a reconstruction, written from a synthetic clip's exact oracle and read back with the
tools people use (numpy, trimesh, pycolmap, rerun, PyAV), checked against the clip's ground truth."""

import json
import struct
import subprocess
import sys
from types import SimpleNamespace

import av
import numpy as np
import pytest
import trimesh
from PIL import Image
from trimesh.transformations import quaternion_matrix

from d4rt.errors import UserError
from d4rt.geometry.camera import pixel_to_uv, unproject_depth
from d4rt.geometry.transforms import apply_transform, invert_rigid, similarity_times_pose
from d4rt.io import exports, formats, output_plan, writers
from d4rt.io.exports import export_reconstruction
from d4rt.io.depth_png import read_depth_png
from d4rt.synthetic import render_clip
from d4rt.viz.overlay import project_tracks
from subprocess_budget import budget

GRID = 5


@pytest.fixture(scope="module")
def clip():
    return render_clip(3, 5, 30, 40, environment="room", num_objects=4, camera_motion="orbit", moving_fraction=0.8)


@pytest.fixture(scope="module")
def saved(clip, tmp_path_factory):
    out = tmp_path_factory.mktemp("exports") / "out"
    names = [f for f in formats.FORMATS if f != "rerun" or formats.rerun_available()]
    paths = export_reconstruction(clip.reconstruction(), out, names, track_grid=GRID, timestamps=np.arange(5) / 12.0,
                                  fps=12.0)
    assert sorted(p.name for p in paths) == sorted(formats.FORMATS[f].split("/")[0].split(" ")[0].rstrip(",")
                                                    for f in names)
    with np.load(out / "reconstruction.npz") as npz:
        return out, dict(npz)


def _gt_poses(clip):
    return invert_rigid(clip.cam_to_world[0]) @ clip.cam_to_world  # world = camera 0


def test_npz_holds_every_array_and_matches_ground_truth(clip, saved):
    _, npz = saved
    t, h, w = clip.depth.shape
    shapes = {"depth": (t, h, w), "confidence": (t, h, w), "intrinsics": (t, 3, 3), "video_intrinsics": (t, 3, 3),
              "cam_to_world": (t, 4, 4), "timestamps": (t,), "points": (t * h * w, 3), "point_colors": (t * h * w, 3),
              "point_confidence": (t * h * w,), "point_frames": (t * h * w,), "point_pixels": (t * h * w, 2),
              "track_queries": (GRID * GRID, 3), "tracks": (GRID * GRID, t, 3), "track_visibility": (GRID * GRID, t),
              "track_confidence": (GRID * GRID, t), "track_uv": (GRID * GRID, t, 2), "video_size": (2,)}
    for key, shape in shapes.items():
        assert npz[key].shape == shape, key
    np.testing.assert_allclose(npz["depth"], clip.depth, rtol=1e-5)
    np.testing.assert_allclose(npz["cam_to_world"], _gt_poses(clip), atol=1e-6)
    np.testing.assert_allclose(npz["video_intrinsics"], clip.intrinsics, rtol=1e-6)
    np.testing.assert_array_equal(npz["intrinsics"], npz["video_intrinsics"])  # depth at the input's size
    # Each point is its pixel's ground-truth depth, unprojected and moved into camera 0.
    f, (x, y) = npz["point_frames"], npz["point_pixels"].T
    cam_points = unproject_depth(clip.depth.astype(np.float64), clip.intrinsics)[f, y, x]
    np.testing.assert_allclose(npz["points"], apply_transform(_gt_poses(clip)[f], cam_points), atol=1e-4)
    np.testing.assert_array_equal(npz["point_colors"], clip.rgb[f, y, x])


def test_dense_tracks_file_matches_ground_truth_and_is_left_out_of_all(clip, saved):
    out, npz = saved
    assert "dense-tracks" not in formats.parse_formats("all") and not any(k.startswith("dense") for k in npz)
    t, h, w = clip.depth.shape
    with np.load(out / "dense_tracks.npz") as dense:
        src, world, cam = dense["sources"], dense["points_world"], dense["points_camera"]
        assert tuple(dense["resolution"]) == (h, w) and float(dense["coverage"]) == 1.0
        assert int(dense["naive_num_queries"]) == t * t * h * w
        assert int(dense["num_queries"]) == len(src) * t < int(dense["naive_num_queries"])
        # Each track's point at frame k, moved into the world (camera 0), is the ground-truth point.
        uv = pixel_to_uv(src[:, 1:].astype(np.float64), h, w)
        for k in (0, t - 1):
            q = np.concatenate([uv, src[:, :1], np.full((len(src), 2), float(k))], 1).astype(np.float64)
            q[:, 4] = 0
            truth = clip.oracle.query(q)["points"].numpy()
            np.testing.assert_allclose(world[:, k], truth, atol=1e-4)
        np.testing.assert_allclose(apply_transform(_gt_poses(clip)[None], cam.astype(np.float64)), world, atol=1e-4)
        assert dense["visibility"][np.arange(len(src)), src[:, 0]].min() == 1  # visible at its own source
    rec = clip.reconstruction()
    with pytest.raises(UserError, match="dense_resolution"):
        output_plan.compute_outputs(rec, ["tum", "dense-tracks"], dense_resolution="huge")
    with pytest.raises(UserError, match="no encoder resolution"):  # the oracle has none
        output_plan.compute_outputs(rec, ["dense-tracks"], dense_resolution="encoder")
    assert rec.queries_decoded == 0  # both refused before any decoding


def test_motion_masks_files_match_the_oracle_and_are_left_out_of_all(clip, saved):
    out, npz = saved
    assert "motion-masks" not in formats.parse_formats("all") and "dynamic" not in npz
    truth = clip.reconstruction().motion_masks()
    assert truth.dynamic.any() and not truth.dynamic.all()  # the premise: some pixels move, some do not
    # The cloud's static / dynamic split: each point flagged by the mask under its pixel (masks at the input's size).
    f, (x, y) = npz["point_frames"], npz["point_pixels"].T
    np.testing.assert_array_equal(npz["point_dynamic"], truth.dynamic[f, y, x])
    with np.load(out / "motion" / "motion.npz") as motion:
        np.testing.assert_array_equal(motion["dynamic"], truth.dynamic)
        np.testing.assert_array_equal(motion["relative_motion"], truth.relative_motion)
        np.testing.assert_array_equal(motion["target_frames"], truth.target_frames)
        assert float(motion["threshold"]) == 0.05 and tuple(motion["resolution"]) == clip.depth.shape[1:]
    for k in range(clip.num_frames):
        png = np.asarray(Image.open(out / "motion" / f"{k:06d}.png"))
        assert png.dtype == np.uint8 and set(np.unique(png)) <= {0, 255}
        np.testing.assert_array_equal(png == 255, truth.dynamic[k])
    rec = clip.reconstruction()
    with pytest.raises(UserError, match="motion_resolution"):
        output_plan.compute_outputs(rec, ["tum", "motion-masks"], motion_resolution="huge")
    with pytest.raises(UserError, match="motion threshold"):
        output_plan.compute_outputs(rec, ["tum", "motion-masks"], motion_threshold=-1.0)
    assert rec.queries_decoded == 0  # refused before any decoding


def test_known_poses_carry_every_output_into_their_world(clip, tmp_path):
    """Poses given in a world and units of their own (here the true cameras through a Sim(3)): the files come out
    in that world, exactly on the oracle: poses equal to the known ones, depth and points scaled and moved."""
    sim = np.eye(4)
    sim[:3, :3] = 2.5 * quaternion_matrix([0.9, 0.1, -0.3, 0.2])[:3, :3]  # (trimesh normalises the quaternion)
    sim[:3, 3] = [1.0, -4.0, 2.0]
    known = np.stack([similarity_times_pose(sim, pose) for pose in _gt_poses(clip)])
    out = tmp_path / "known"
    export_reconstruction(clip.reconstruction(), out, ["npz", "colmap"], track_grid=GRID, known_poses=known)
    with np.load(out / "reconstruction.npz") as npz:
        np.testing.assert_allclose(npz["cam_to_world"], known, atol=1e-5)
        np.testing.assert_allclose(npz["alignment"], sim, atol=1e-6)
        assert float(npz["alignment_rms"]) < 1e-5
        np.testing.assert_allclose(npz["depth"], 2.5 * clip.depth, rtol=1e-5)
        f, (x, y) = npz["point_frames"], npz["point_pixels"].T
        cam_points = unproject_depth(clip.depth.astype(np.float64), clip.intrinsics)[f, y, x]
        world = apply_transform(_gt_poses(clip)[f], cam_points)
        np.testing.assert_allclose(npz["points"], world @ sim[:3, :3].T + sim[:3, 3], atol=1e-3)
        tracks = npz["tracks"]
    truth = clip.reconstruction().tracks(np.concatenate([np.zeros((GRID * GRID, 1)), npz_track_pixels(clip)], 1),
                                         frame="world")
    np.testing.assert_allclose(tracks, truth.points @ sim[:3, :3].T + sim[:3, 3], atol=1e-4)
    scaled = tmp_path / "scaled"
    export_reconstruction(clip.reconstruction(), scaled, ["npz"], track_grid=GRID, scale=0.1)
    with np.load(scaled / "reconstruction.npz") as npz:
        np.testing.assert_allclose(npz["depth"], 0.1 * clip.depth, rtol=1e-5)
        np.testing.assert_allclose(npz["cam_to_world"][:, :3, 3], 0.1 * _gt_poses(clip)[:, :3, 3], atol=1e-6)
        np.testing.assert_allclose(npz["cam_to_world"][:, :3, :3], _gt_poses(clip)[:, :3, :3], atol=1e-6)
    rec = clip.reconstruction()
    for options, message in (({"scale": 0.0}, "scale must be a finite number > 0"),
                             ({"scale": 2.0, "known_poses": known}, "not both"),
                             ({"known_poses": known[:3]}, r"known poses must be \(5, 4, 4\)")):
        with pytest.raises(UserError, match=message):
            output_plan.compute_outputs(rec, ["npz"], **options)
    assert rec.queries_decoded == 0  # refused before any decoding


def npz_track_pixels(clip) -> np.ndarray:
    """The (x, y) pixels of the GRID x GRID tracks the exports start from frame 0."""
    from d4rt.geometry.camera import cell_centres_uv, uv_to_pixel
    return uv_to_pixel(cell_centres_uv(GRID), clip.height, clip.width)


def test_known_intrinsics_hold_at_another_output_resolution(clip, tmp_path):
    """Intrinsics given in input pixels are rescaled for depth maps of another size (here another aspect
    ratio too): unprojecting the saved depth with the saved intrinsics gives the true 3D points."""
    h, w = 21, 17
    assert np.ptp(clip.intrinsics[:, 0, 0]) > 1  # this clip zooms: one K per frame
    export_reconstruction(clip.reconstruction(), tmp_path / "o", ["npz"], resolution=(h, w),
                          intrinsics=clip.intrinsics)
    with np.load(tmp_path / "o" / "reconstruction.npz") as npz:
        depth, k = npz["depth"], npz["intrinsics"]
        np.testing.assert_array_equal(npz["video_intrinsics"], clip.intrinsics)
    assert depth.shape == (5, h, w)
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    uv = pixel_to_uv(np.stack([xs, ys], -1).reshape(-1, 2).astype(np.float64), h, w)
    for t in (0, 4):
        q = np.concatenate([uv, np.full((len(uv), 3), float(t))], 1)
        truth = clip.oracle.query(q)["points"].numpy().reshape(h, w, 3)
        np.testing.assert_allclose(unproject_depth(depth[t].astype(np.float64), k[t]), truth, atol=1e-4)


def test_depth_pngs_round_trip(clip, saved):
    out, _ = saved
    scale = json.loads((out / "depth" / "depth_scale.json").read_text())["depth_scale"]
    assert sorted(p.name for p in (out / "depth").glob("*.png")) == [f"{i:06d}.png" for i in range(5)]
    for t in (0, 4):
        back = read_depth_png(out / "depth" / f"{t:06d}.png", scale)
        np.testing.assert_allclose(back, clip.depth[t], atol=0.5 / scale + 1e-6)


def test_confidence_threshold_filters_points_and_depth_pixels(clip, tmp_path):
    rec = clip.reconstruction()  # the oracle's confidence is 1 wherever it answers
    kept = output_plan.compute_outputs(rec, ["ply", "depth"], min_confidence=0.5, point_stride=4)
    assert len(kept.points) == 5 * 8 * 10 and kept.depth_valid().all()
    # A threshold that leaves nothing is an error naming the range found, not an empty file.
    for names, source, what in ((["ply"], "queries", "no point"), (["ply"], "depth", "no depth pixel"),
                                (["depth"], "depth", "no depth pixel")):
        with pytest.raises(UserError, match=f"{what} has confidence >= 1.5 .*confidences are all 1\\)"):
            output_plan.compute_outputs(rec, names, min_confidence=1.5, point_stride=4, points_from=source)
    # Pixels below the threshold are 0 (no depth) in the PNGs.
    kept.confidence[1:] = 0.25
    writers.write_outputs(kept, tmp_path / "o", ["depth"])
    scale = json.loads((tmp_path / "o" / "depth" / "depth_scale.json").read_text())["depth_scale"]
    assert read_depth_png(tmp_path / "o" / "depth" / "000000.png", scale).all()
    assert not read_depth_png(tmp_path / "o" / "depth" / "000001.png", scale).any()


def _read_ply(path):
    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    lines = head.decode("ascii").splitlines()
    count = int(next(line for line in lines if line.startswith("element vertex")).split()[-1])
    props = [tuple(line.split()[1:]) for line in lines if line.startswith("property")]
    kinds = {"float": "<f4", "uchar": "u1", "int": "<i4"}
    return lines, np.frombuffer(body, dtype=np.dtype([(n, kinds[k]) for k, n in props]), count=count)


def test_ply_header_count_and_values(saved):
    out, npz = saved
    lines, vertices = _read_ply(out / "points.ply")
    assert lines[1] == "format binary_little_endian 1.0" and len(vertices) == len(npz["points"])
    np.testing.assert_array_equal(np.stack([vertices[a] for a in "xyz"], 1), npz["points"])
    np.testing.assert_array_equal(np.stack([vertices[c] for c in ("red", "green", "blue")], 1), npz["point_colors"])
    np.testing.assert_array_equal(vertices["frame"], npz["point_frames"])


def test_glb_loads_with_trimesh_in_gltf_axes(saved):
    out, npz = saved
    scene = trimesh.load(out / "scene.glb")
    assert set(scene.geometry) == {"points", "cameras"}
    transform, name = scene.graph["points"]
    cloud = trimesh.transform_points(scene.geometry[name].vertices, transform)
    np.testing.assert_allclose(cloud, npz["points"] * [1, -1, -1], atol=1e-5)  # OpenCV -> glTF (y up)
    transform, name = scene.graph["cameras"]
    assert isinstance(scene.geometry[name], trimesh.path.Path3D)
    lines = trimesh.transform_points(scene.geometry[name].vertices, transform)
    for centre in npz["cam_to_world"][:, :3, 3] * [1, -1, -1]:  # every frustum's apex is its camera centre
        assert np.linalg.norm(lines - centre, axis=1).min() < 1e-5


def test_colmap_model_reads_with_pycolmap_and_reprojects(clip, saved):
    """The zooming clip: one PINHOLE camera per frame, the true poses, and points seen in 2 or more frames
    whose observations reproject within the filter (1% of the longer side) and their stored mean error."""
    pycolmap = pytest.importorskip("pycolmap")
    out, npz = saved
    rec = pycolmap.Reconstruction(str(out / "colmap" / "sparse" / "0"))
    assert rec.num_images() == 5 and rec.num_cameras() == 5 and 0 < rec.num_points3D() <= len(npz["points"])
    for image_id, image in rec.images.items():
        t = image_id - 1
        assert (out / "colmap" / "images" / image.name).is_file()
        fx, fy, cx, cy = image.camera.params
        k = clip.intrinsics[t]
        np.testing.assert_allclose([fx, fy, cx, cy], [k[0, 0], k[1, 1], k[0, 2] + 0.5, k[1, 2] + 0.5], rtol=1e-6)
        np.testing.assert_allclose(image.projection_center(), _gt_poses(clip)[t, :3, 3], atol=1e-6)
    errors = _reprojection_errors(rec)
    assert max(max(e) for e in errors.values()) <= 0.01 * 40 + 1e-9
    for point_id, point in rec.points3D.items():
        assert point.track.length() >= 2 and np.isclose(point.error, np.mean(errors[point_id]), atol=1e-9)


def _reprojection_errors(rec) -> dict:
    """point3D id -> reprojection errors (pixels) of its observations, recomputed with pycolmap."""
    errors = {}
    for image in rec.images.values():
        for point in image.points2D:
            if point.has_point3D():
                xyz = rec.points3D[point.point3D_id].xyz
                projected = image.camera.img_from_cam(image.cam_from_world() * xyz)
                errors.setdefault(point.point3D_id, []).append(float(np.linalg.norm(projected - point.xy)))
    return errors


def test_colmap_points_are_tracks_that_survive_bundle_adjustment(tmp_path):
    """A static scene on the oracle: every COLMAP point is a track seen in several frames that reprojects
    onto its observations (1e-3 px), the cloud is bounded by max_points, and pycolmap's bundle adjustment
    runs on the model and leaves the exact cameras where they are."""
    pycolmap = pytest.importorskip("pycolmap")
    clip = render_clip(6, 6, 36, 48, environment="room", num_objects=3, moving_fraction=0.0, articulated=False,
                       camera_motion="orbit", zoom=False)
    export_reconstruction(clip.reconstruction(), tmp_path / "o", ["colmap"], max_points=300, track_grid=0)
    rec = pycolmap.Reconstruction(str(tmp_path / "o" / "colmap" / "sparse" / "0"))
    assert rec.num_cameras() == 1 and 100 < rec.num_points3D() <= 300  # one shared camera, a bounded cloud
    errors = _reprojection_errors(rec)
    assert max(max(e) for e in errors.values()) < 1e-3
    lengths = np.array([p.track.length() for p in rec.points3D.values()])
    assert lengths.min() >= 2 and lengths.mean() > 3
    assert max(p.error for p in rec.points3D.values()) < 1e-3
    centres = np.array([rec.images[i + 1].projection_center() for i in range(6)])
    pycolmap.bundle_adjustment(rec)
    moved = np.array([rec.images[i + 1].projection_center() for i in range(6)]) - centres
    assert np.abs(moved).max() < 1e-6 and rec.compute_mean_reprojection_error() < 1e-3
    np.testing.assert_allclose(centres, _gt_poses(clip)[:, :3, 3], atol=1e-6)


def test_tum_trajectory(clip, saved):
    out, _ = saved
    rows = np.array([[float(v) for v in line.split()] for line in (out / "trajectory_tum.txt").read_text().splitlines()
                     if not line.startswith("#")])
    assert rows.shape == (5, 8)
    np.testing.assert_allclose(rows[:, 0], np.arange(5) / 12.0, atol=1e-6)
    gt = _gt_poses(clip)
    np.testing.assert_allclose(rows[:, 1:4], gt[:, :3, 3], atol=1e-6)
    for row, pose in zip(rows, gt):
        qx, qy, qz, qw = row[4:]
        np.testing.assert_allclose(quaternion_matrix([qw, qx, qy, qz])[:3, :3], pose[:3, :3], atol=1e-6)


def _decode(path):
    with av.open(str(path)) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


def test_videos_and_track_projections(clip, saved):
    out, npz = saved
    depth_video = _decode(out / "depth.mp4")  # frame | depth | colour bar, enlarged 6x to 180 pixels high
    assert depth_video.shape[:2] == (5, 180) and depth_video.shape[2] > 2 * 240
    frame = np.asarray(Image.fromarray(clip.rgb[0]).resize((240, 180), Image.BILINEAR)).astype(float)
    assert np.abs(depth_video[0, :, :240] - frame).mean() < 6  # the input frame on the left (H.264 loss)
    assert _decode(out / "tracks.mp4").shape == (5, 30, 40, 3)
    # The overlay draws the 3D tracks projected through the cameras: on the oracle, the true 2D tracks.
    xy, z = project_tracks(npz["tracks"], npz["video_intrinsics"], npz["cam_to_world"])
    true_xy = npz["track_uv"] * [40, 30] - 0.5
    seen = npz["track_visibility"] > 0.5
    assert seen.mean() > 0.3 and (z[seen] > 0).all()
    np.testing.assert_allclose(xy[seen], true_xy[seen], atol=1e-4)


def test_rerun_recording_verifies(saved):
    pytest.importorskip("rerun", reason="rerun-sdk is an optional extra (pip install 'd4rt[viewer]')")
    out, _ = saved
    rrd = out / "reconstruction.rrd"
    verify = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(rrd)], capture_output=True,
                            text=True, timeout=budget(120))
    assert verify.returncode == 0, verify.stderr
    listing = subprocess.run([sys.executable, "-m", "rerun", "rrd", "print", str(rrd)], capture_output=True,
                             text=True, timeout=budget(120)).stdout
    for entity in ("world/camera", "world/camera/image", "world/points", "world/tracks", "depth"):
        assert entity in listing, entity


def test_failed_save_leaves_nothing_behind(clip, tmp_path, monkeypatch):
    rec = clip.reconstruction()

    def broken(*args):
        raise OSError("disk full")

    monkeypatch.setitem(writers._WRITERS, "tum", broken)
    target = tmp_path / "deeper" / "out"
    with pytest.raises(OSError, match="disk full"):
        export_reconstruction(rec, target, ["ply", "tum"], point_stride=4)
    assert list(tmp_path.iterdir()) == []  # no output folder, no parents, no staging folder

    target.mkdir(parents=True)
    (target / "points.ply").write_text("old")
    (target / "stale.txt").write_text("an earlier run's")
    with pytest.raises(OSError):
        export_reconstruction(rec, target, ["ply", "tum"], point_stride=4, overwrite=True)
    assert (target / "points.ply").read_text() == "old" and sorted(p.name for p in target.parent.iterdir()) == ["out"]
    monkeypatch.undo()
    export_reconstruction(rec, target, ["ply"], point_stride=4, overwrite=True)  # the folder as a whole is replaced
    assert sorted(p.name for p in target.iterdir()) == ["points.ply"]
    assert (target / "points.ply").read_bytes().startswith(b"ply\n")
    assert sorted(p.name for p in target.parent.iterdir()) == ["out"]  # no staging or old folder left


def test_a_non_empty_output_folder_is_refused_before_any_work(clip, tmp_path, monkeypatch):
    """Another run's files never end up beside this run's: a non-empty folder needs overwrite."""
    target = tmp_path / "out"
    target.mkdir()
    (target / "mine.txt").write_text("keep")
    rec = clip.reconstruction()
    monkeypatch.setattr(exports, "compute_outputs", lambda *a, **k: pytest.fail("decoded before refusing"))
    with pytest.raises(UserError, match="is not empty: pass --overwrite"):
        export_reconstruction(rec, target, ["tum"])
    assert [p.name for p in target.iterdir()] == ["mine.txt"]
    monkeypatch.undo()
    (target / "mine.txt").unlink()
    export_reconstruction(rec, target, ["tum"])  # an empty folder is fine
    assert [p.name for p in target.iterdir()] == ["trajectory_tum.txt"]


def test_format_names_and_missing_rerun(clip, tmp_path, monkeypatch, capsys):
    with pytest.raises(UserError, match="unknown output format"):
        formats.parse_formats("ply,obj")
    assert formats.parse_formats("tum, ply") == ["ply", "tum"]
    monkeypatch.setattr(formats, "rerun_available", lambda: False)
    with pytest.raises(UserError, match="needs the rerun-sdk package"):
        formats.parse_formats("rerun")
    assert "rerun" not in formats.parse_formats("all")
    assert capsys.readouterr().err.count("\n") == 1  # a one-line notice
    (tmp_path / "file").write_text("")
    with pytest.raises(UserError, match="not a directory"):
        export_reconstruction(clip.reconstruction(), tmp_path / "file", ["tum"])


def test_binary_layout_of_the_colmap_files(saved):
    """The files follow COLMAP's binary layout byte for byte (read here without pycolmap)."""
    out, npz = saved
    data = (out / "colmap" / "sparse" / "0" / "points3D.bin").read_bytes()
    (count,) = struct.unpack_from("<Q", data)
    offset, lengths = 8, []
    for expected_id in range(1, count + 1):
        point_id, x, y, z, r, g, b, error, track_length = struct.unpack_from("<QdddBBBdQ", data, offset)
        offset += 51 + 8 * track_length
        assert point_id == expected_id and track_length >= 2 and error >= 0
        lengths.append(track_length)
        pairs = np.frombuffer(data, dtype="<i4", count=2 * track_length, offset=offset - 8 * track_length)
        assert set(pairs[0::2]) <= set(range(1, 6))  # image ids
    assert offset == len(data) and count > 0


@pytest.mark.parametrize("points_from", ["depth", "queries"])
def test_outputs_spooled_to_disk_equal_the_in_memory_ones(tmp_path, monkeypatch, points_from):
    """compute_outputs(spool=DIR) (what export_reconstruction and the CLI use: depth maps and point cloud
    written to disk a window and a block of frames at a time, the frames read from disk) gives the same
    arrays and files as the in-memory path, over several windows and several point blocks."""
    from d4rt.disk_array import DiskArray
    from d4rt.reconstruction import Reconstruction

    long_clip = render_clip(5, 10, 24, 32, environment="room", num_objects=3, camera_motion="orbit")
    frames_on_disk = DiskArray.create(tmp_path / "frames.raw", long_clip.rgb.shape, np.uint8)
    frames_on_disk[0:10] = long_clip.rgb
    monkeypatch.setattr(output_plan, "POINT_BLOCK_PIXELS", 3 * 24 * 32)  # 3 frames a block
    options = dict(track_grid=3, max_points=150, points_from=points_from, min_confidence=0.5)
    names = ["npz", "depth", "ply", "colmap", "tum", "html"]
    in_memory = output_plan.compute_outputs(long_clip.reconstruction(window=4, overlap=1), names, **options)
    spool = tmp_path / "spool"
    spool.mkdir()
    rec = Reconstruction.from_clip(SimpleNamespace(oracle=long_clip.oracle, rgb=frames_on_disk), window=4, overlap=1)
    on_disk = output_plan.compute_outputs(rec, names, spool=spool, **options)
    assert isinstance(on_disk.depth, DiskArray) and isinstance(on_disk.points, DiskArray)
    for name in ("depth", "confidence", "points", "point_colors", "point_confidence", "point_frames", "point_pixels",
                 "video_intrinsics", "cam_to_world", "tracks", "point_offsets"):
        mine, theirs = np.asarray(getattr(on_disk, name)), np.asarray(getattr(in_memory, name))
        assert mine.dtype == theirs.dtype, name
        np.testing.assert_array_equal(mine, theirs, err_msg=name)
    np.testing.assert_array_equal(in_memory.point_offsets, np.searchsorted(in_memory.point_frames, np.arange(11)))
    for key in in_memory.colmap:
        np.testing.assert_array_equal(on_disk.colmap[key], in_memory.colmap[key], err_msg=key)
    writers.write_outputs(in_memory, tmp_path / "a" / "out", names)  # one folder name: the page's title
    writers.write_outputs(on_disk, tmp_path / "b" / "out", names)
    for relative in ["points.ply", "trajectory_tum.txt", "viewer.html", "colmap/sparse/0/points3D.bin",
                     *[f"depth/{k:06d}.png" for k in range(10)], *[f"colmap/images/{k:06d}.png" for k in range(10)]]:
        assert (tmp_path / "a/out" / relative).read_bytes() == (tmp_path / "b/out" / relative).read_bytes(), relative
    with np.load(tmp_path / "a/out/reconstruction.npz") as a, np.load(tmp_path / "b/out/reconstruction.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_spread_subset_reduces_a_cloud_block_by_block():
    """The COLMAP points of a cloud too large for one block: at most max_points, spread over the whole
    cloud (every block's region keeps points), the best-scored of each voxel."""
    rng = np.random.default_rng(0)
    points = np.concatenate([rng.uniform(0, 1, (3000, 3)) + [2.0 * k, 0, 0] for k in range(4)])
    score = rng.uniform(0, 1, len(points))
    pick = output_plan.spread_subset(points, score, 200, block=2500)
    assert len(pick) <= 200 and len(np.unique(pick)) == len(pick) and np.all(np.diff(pick) > 0)
    counts = np.bincount((points[pick, 0] // 2).astype(int), minlength=4)
    assert counts.min() >= 35, counts  # each unit cube keeps its share (about 50)
    whole = output_plan.spread_subset(points, score, 200)  # in one block
    assert len(whole) <= 200 and len(pick) >= 0.8 * len(whole)
