"""The query recipes, run on the synthetic engine's exact oracle, must reproduce ground truth."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from d4rt.errors import UserError
from d4rt.geometry.camera import project, unproject_depth
from d4rt.geometry.transforms import apply_transform, invert_rigid
from d4rt.config import D4RTConfig
from d4rt.reconstruction import Reconstruction, plan_windows
from d4rt.synthetic import render_clip


def rotation_error_deg(a, b):
    r = a[..., :3, :3] @ np.swapaxes(b[..., :3, :3], -1, -2)
    return np.degrees(np.arccos(np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))


@pytest.fixture(scope="module")
def busy_clip():
    """Moving objects cover a large part of the view: they must not corrupt the camera fit."""
    clip = render_clip(13, 10, 48, 64, environment="room", num_objects=8, moving_fraction=1.0,
                       camera_motion="handheld", fov_degrees=(35, 40))
    moving = [k for k, kind in enumerate(clip.scene.info["body_motion"]) if kind not in ("environment", "static")]
    fraction = np.isin(clip.object_ids, moving).mean()
    assert fraction > 0.25, fraction  # the premise of the test
    return clip


def test_depth_equals_the_rendered_depth(room_clip):
    d = room_clip.reconstruction().depth()
    assert d.depth.shape == room_clip.depth.shape and d.confidence.shape == room_clip.depth.shape
    rel = np.abs(d.depth - room_clip.depth) / room_clip.depth
    assert np.median(rel) < 1e-7 and rel.max() < 4e-6
    assert (d.confidence == 1).all()


def test_depth_at_another_resolution_is_exact_too(outdoor_clip):
    rec = outdoor_clip.reconstruction()
    d = rec.depth(resolution=(20, 36)).depth  # half size: pixel centres fall between the originals
    k = outdoor_clip.intrinsics.copy()
    k[:, 0] *= 0.5
    k[:, 1] *= 0.5
    k[:, 0, 2] = (36 - 1) / 2 + (outdoor_clip.intrinsics[:, 0, 2] - (72 - 1) / 2) * 0.5
    k[:, 1, 2] = (20 - 1) / 2 + (outdoor_clip.intrinsics[:, 1, 2] - (40 - 1) / 2) * 0.5
    ref = outdoor_clip.resize(20, 36)  # re-rendered exactly on that grid
    assert np.allclose(ref.intrinsics, k)
    assert np.abs(d - ref.depth).max() / ref.depth.max() < 4e-6


def test_point_cloud_equals_the_ground_truth_cloud_in_the_reference_camera(room_clip):
    ref = 3
    pc = room_clip.reconstruction().point_cloud(reference_frame=ref, stride=2)
    f, x, y = pc.frames, pc.pixels[:, 0], pc.pixels[:, 1]
    cam = unproject_depth(room_clip.depth.astype(np.float64), room_clip.intrinsics)[f, y, x]
    world = apply_transform(room_clip.cam_to_world[f], cam)
    expected = apply_transform(invert_rigid(room_clip.cam_to_world[ref]), world)
    assert len(pc.points) == room_clip.num_frames * 24 * 32
    assert np.abs(pc.points - expected).max() < 1e-4 * np.abs(expected).max()
    assert np.array_equal(pc.colors, room_clip.rgb[f, y, x])
    seen = room_clip.reconstruction().point_cloud(reference_frame=ref, stride=4, visible_only=True)
    assert 0 < len(seen.points) < room_clip.num_frames * 12 * 16  # occluded / out-of-view points dropped


def test_cameras_are_exact_despite_large_moving_objects(busy_clip):
    cams = busy_clip.reconstruction().cameras()
    gt = invert_rigid(busy_clip.cam_to_world[0]) @ busy_clip.cam_to_world
    scale = np.linalg.norm(gt[:, :3, 3], axis=1).max() + 1.0
    assert rotation_error_deg(cams.cam_to_world, gt).max() < 0.01
    assert np.abs(cams.cam_to_world[:, :3, 3] - gt[:, :3, 3]).max() < 1e-4 * scale
    focal_err = np.abs(cams.intrinsics[:, 0, 0] / busy_clip.intrinsics[:, 0, 0] - 1)
    assert focal_err.max() < 1e-3
    assert np.allclose(cams.intrinsics[:, :2, 2], busy_clip.intrinsics[:, :2, 2])
    # Another reference frame: the world is that camera.
    cams5 = busy_clip.reconstruction().cameras(reference_frame=5)
    assert np.allclose(cams5.cam_to_world[5], np.eye(4), atol=1e-12)


def test_least_squares_intrinsics_are_exact_for_an_off_centre_principal_point():
    clip = render_clip(4, 3, 40, 56, principal_point_jitter=0.12, zoom=True, num_objects=3)
    rec = clip.reconstruction()
    fit = rec.cameras(method="lstsq").intrinsics
    assert np.abs(fit - clip.intrinsics).max() < 1e-6 * clip.intrinsics[:, 0, 0].max()
    median = rec.cameras(method="median").intrinsics  # assumes a centred principal point: biased here
    assert np.abs(median[:, :2, 2] - clip.intrinsics[:, :2, 2]).max() > 1.0
    known = rec.cameras(intrinsics=clip.intrinsics[0]).intrinsics
    assert np.array_equal(known, np.broadcast_to(clip.intrinsics[0], known.shape))
    with pytest.raises(UserError, match="intrinsics"):
        rec.cameras(intrinsics=np.eye(4))


def test_one_shared_square_pixel_camera_is_exact_for_a_video_without_zoom():
    """camera="single" pools every frame's grid points into one camera; with square pixels one focal length
    fits x and y together. Exact on the oracle, for both recipes (lstsq also finds an off-centre point)."""
    clip = render_clip(5, 6, 36, 60, zoom=False, principal_point_jitter=0.1, num_objects=3)
    assert np.allclose(clip.intrinsics, clip.intrinsics[:1])  # one true camera
    rec = clip.reconstruction()
    single = rec.cameras(method="lstsq", camera="single", square_pixels=True).intrinsics
    assert np.abs(single - clip.intrinsics).max() < 1e-6 * clip.intrinsics[0, 0, 0]
    centred = render_clip(5, 6, 36, 60, zoom=False, num_objects=3)
    median = centred.reconstruction().cameras(camera="single", square_pixels=True).intrinsics
    assert np.abs(median - centred.intrinsics).max() < 1e-6 * centred.intrinsics[0, 0, 0]
    with pytest.raises(UserError, match="camera must be one of"):
        rec.cameras(camera="shared")


def test_exports_keep_one_camera_unless_the_video_zooms(tmp_path, capsys):
    """The exports' default ("auto"): one camera where the per-frame focal lengths agree, per-frame
    cameras (with a notice) where they do not; every export uses the same intrinsics."""
    from d4rt.io.output_plan import compute_outputs

    steady = render_clip(5, 6, 36, 60, zoom=False, num_objects=3)
    out = compute_outputs(steady.reconstruction(), ["npz"], track_grid=0)
    assert np.allclose(out.video_intrinsics, steady.intrinsics, rtol=1e-9)
    assert (out.video_intrinsics == out.video_intrinsics[:1]).all() and "focal lengths" not in capsys.readouterr().err
    zooming = next(c for c in (render_clip(s, 6, 36, 60, zoom=True, num_objects=3) for s in range(20))
                   if c.intrinsics[-1, 0, 0] / c.intrinsics[0, 0, 0] > 1.3)
    out = compute_outputs(zooming.reconstruction(), ["npz"], track_grid=0)
    assert np.allclose(out.video_intrinsics, zooming.intrinsics, rtol=1e-6)
    assert "each frame keeps its own camera" in capsys.readouterr().err
    forced = compute_outputs(zooming.reconstruction(), ["tum"], camera="single")
    assert (forced.video_intrinsics == forced.video_intrinsics[:1]).all()


def test_point_clouds_from_depth_and_cameras_equal_the_direct_recipe(clip):
    """The exports' default cloud (depth maps unprojected through the cameras, no further query) and the
    paper's direct recipe (t_cam = 0) give the same points on exact answers, for one window and for
    windows stitched by Sim(3)."""
    from d4rt.io.output_plan import compute_outputs

    for rec in (clip.reconstruction(), clip.reconstruction(window=5, overlap=2)):
        derived = compute_outputs(rec, ["ply"], point_stride=3, camera="per-frame")
        direct = compute_outputs(rec, ["ply"], point_stride=3, points_from="queries", camera="per-frame")
        assert np.array_equal(derived.point_pixels, direct.point_pixels)
        assert np.array_equal(derived.point_frames, direct.point_frames)
        assert np.array_equal(derived.point_colors, direct.point_colors)
        scale = np.abs(direct.points).max()
        np.testing.assert_allclose(derived.points, direct.points, atol=1e-5 * scale)


def test_tracks_in_world_and_camera_frames(room_clip):
    rec = room_clip.reconstruction()
    rng = np.random.default_rng(0)
    n, t = 300, room_clip.num_frames
    pts = np.stack([rng.integers(0, t, n), rng.integers(0, 64, n), rng.integers(0, 48, n)], 1).astype(float)
    world = rec.tracks(pts, frame="world", reference_frame=0)
    cam = rec.tracks(pts, frame="camera")
    assert world.points.shape == (n, t, 3) and world.visibility.shape == (n, t)
    ids = room_clip.object_ids[pts[:, 0].astype(int), pts[:, 2].astype(int), pts[:, 1].astype(int)]
    static = np.isin(ids, [k for k, kind in enumerate(room_clip.scene.info["body_motion"])
                           if kind in ("environment", "static")])
    spread = np.abs(world.points - world.points[:, :1]).max((1, 2))
    assert static.sum() > 50 and spread[static].max() < 1e-9 * np.abs(world.points).max()
    assert spread[~static].max() > 1e-2  # moving points do move
    # Camera-frame tracks project to the ground-truth 2D track (the oracle's uv at every frame).
    xy, z = project(cam.points, room_clip.intrinsics[None])
    uv = (xy + 0.5) / np.array([64, 48])
    front = z > 0
    assert np.abs(uv - cam.uv)[front].max() < 1e-9
    # Each track passes through its own query pixel, visibly, at t_src.
    rows = np.arange(n)
    assert np.allclose(cam.uv[rows, pts[:, 0].astype(int)], (pts[:, 1:] + 0.5) / np.array([64, 48]))
    assert (cam.visibility[rows, pts[:, 0].astype(int)] == 1).all()
    with pytest.raises(UserError, match="t_src"):
        rec.tracks([[8, 1, 1]])
    with pytest.raises(UserError, match="image"):
        rec.tracks([[0, 64, 1]])


def test_dense_tracking_covers_every_pixel_with_far_fewer_queries():
    clip = render_clip(3, 16, 48, 64, environment="room", num_objects=6, camera_motion="orbit", articulated=True,
                       moving_fraction=0.8)  # a typical clip: moving camera, moving and occluding objects
    dense = clip.reconstruction().dense_tracks(batch_size=256)
    t = clip.num_frames
    assert dense.coverage == 1.0
    assert dense.naive_num_queries == t * t * 48 * 64
    assert dense.num_queries == len(dense.sources) * t
    assert dense.query_reduction >= 5, dense.query_reduction
    print(f"dense tracking: {dense.query_reduction:.1f}x fewer queries than naive")
    # Every track starts visibly at its source pixel.
    src = dense.sources
    uv = dense.tracks.uv[np.arange(len(src)), src[:, 0]]
    assert np.allclose(uv, (src[:, 1:] + 0.5) / np.array([64, 48]))


def test_dense_tracking_spans_windows_and_matches_the_whole_clip():
    """A video of several windows is tracked densely as a whole: the grid covers every frame, and each
    track, carried from window to window, equals the same track decoded from the whole clip."""
    clip = render_clip(5, 12, 24, 32, environment="room", num_objects=4, camera_motion="orbit", moving_fraction=0.8)
    split = clip.reconstruction(window=6, overlap=2)
    assert len(split.windows) >= 3
    dense = split.dense_tracks(batch_size=128)
    assert dense.coverage == 1.0 and dense.naive_num_queries == 12 * 12 * 24 * 32
    assert dense.tracks.points.shape == (len(dense.sources), 12, 3)
    # Each window decodes only its own frames of the tracks it holds, so fewer than N * T queries.
    assert 0 < dense.num_queries < len(dense.sources) * 12 * 1.5 and dense.query_reduction > 3
    src = dense.sources.astype(float)
    whole = clip.reconstruction().tracks(src, frame="camera")
    carried = np.isfinite(dense.tracks.points).all(2)
    assert carried.mean() > 0.8
    assert np.abs(dense.tracks.points - whole.points)[carried].max() < 1e-6 * np.abs(whole.points).max()
    assert np.array_equal(dense.tracks.visibility[carried], whole.visibility[carried])
    # A different grid resolution maps its cells to the same normalised positions.
    coarse = split.dense_tracks(resolution=(12, 16), batch_size=64)
    rows = np.arange(len(coarse.sources))
    uv = coarse.tracks.uv[rows, coarse.sources[:, 0]]
    assert coarse.coverage == 1.0 and np.allclose(uv, (coarse.sources[:, 1:] + 0.5) / np.array([16, 12]))


def test_a_track_that_cannot_be_handed_back_keeps_its_own_windows_frames():
    """Hidden in every frame two windows share, a track cannot be carried into the earlier window: the
    frames its own window shares with it keep that window's answers, the frames before stay NaN."""
    clip = render_clip(8, 12, 24, 32, environment="room", num_objects=3, camera_motion="orbit")

    class HiddenInOverlaps:
        num_frames = clip.num_frames

        def __init__(self, shared):
            self.shared = shared

        def query(self, q):
            out = dict(clip.oracle.query(q))
            hidden = torch.isin(torch.as_tensor(q[:, 3]).round().long(), self.shared)
            out["visibility"] = torch.where(hidden, torch.zeros_like(out["visibility"]), out["visibility"])
            return out

    windows = plan_windows(12, 6, 2)
    (a0, b0), (a1, b1) = windows[0], windows[1]
    rec = Reconstruction(HiddenInOverlaps(torch.arange(a1, b0)), clip.rgb, window=6, overlap=2)
    assert rec.windows == windows
    tr = rec.tracks([[b0, 10, 10], [b0, 20, 5]])  # both start in window 1, past the overlap
    whole = clip.reconstruction().tracks([[b0, 10, 10], [b0, 20, 5]])
    assert np.isnan(tr.points[:, :a1]).all() and (tr.visibility[:, :a1] == 0).all()
    np.testing.assert_allclose(tr.points[:, a1:b1], whole.points[:, a1:b1], atol=1e-9)


def test_windows_plan():
    assert plan_windows(10, None) == [(0, 10)]
    assert plan_windows(10, 12) == [(0, 10)]
    w = plan_windows(30, 10, 3)
    assert w[0] == (0, 10) and w[-1][1] == 30 and all(b - a == 10 for a, b in w)
    assert all(w[i + 1][0] <= w[i][1] - 3 for i in range(len(w) - 1))
    with pytest.raises(UserError, match="overlap"):
        plan_windows(30, 10, 10)


def test_a_video_three_windows_long_is_stitched_exactly():
    clip = render_clip(8, 24, 32, 48, environment="room", num_objects=5, camera_motion="orbit", moving_fraction=0.8)
    whole = clip.reconstruction()
    split = clip.reconstruction(window=8, overlap=3)
    assert len(split.windows) >= 3
    gt = invert_rigid(clip.cam_to_world[0]) @ clip.cam_to_world
    cams = split.cameras()
    scale = np.linalg.norm(gt[:, :3, 3], axis=1).max() + 1.0
    assert rotation_error_deg(cams.cam_to_world, gt).max() < 0.01
    assert np.abs(cams.cam_to_world[:, :3, 3] - gt[:, :3, 3]).max() < 1e-4 * scale
    assert np.abs(cams.intrinsics[:, 0, 0] / clip.intrinsics[:, 0, 0] - 1).max() < 1e-3
    for sim in split.window_to_world:
        assert abs(float(sim.scale) - 1) < 1e-9  # the oracle's windows share the metric scale
    assert np.abs(split.depth().depth - whole.depth().depth).max() < 1e-4
    a = split.point_cloud(reference_frame=20, stride=4)
    b = whole.point_cloud(reference_frame=20, stride=4)
    assert np.abs(a.points - b.points).max() < 1e-6 * np.abs(b.points).max()
    # Tracks carried across windows match the whole-clip tracks wherever they could be carried.
    rng = np.random.default_rng(1)
    pts = np.stack([rng.integers(0, 24, 200), rng.integers(0, 48, 200), rng.integers(0, 32, 200)], 1).astype(float)
    for frame in ("camera", "world"):
        ta, tb = split.tracks(pts, frame=frame, reference_frame=2), whole.tracks(pts, frame=frame, reference_frame=2)
        carried = np.isfinite(ta.points).all(2)
        assert carried.mean() > 0.8
        assert np.abs(ta.points - tb.points)[carried].max() < 1e-6 * np.abs(tb.points).max()
        assert np.array_equal(ta.visibility[carried], tb.visibility[carried])


def test_observe_gives_the_world_tracks_at_the_chosen_frames():
    """Sparse observations (the COLMAP model's queries) are the full world tracks at the chosen frames,
    for one window and for stitched windows; a -1 column stays empty and a frame outside the source's
    window is refused."""
    from d4rt.io.output_plan import observation_frames

    clip = render_clip(5, 12, 24, 32, environment="room", num_objects=4, camera_motion="orbit", moving_fraction=0.5)
    rng = np.random.default_rng(0)
    starts = np.stack([rng.integers(0, 12, 40), rng.uniform(0, 31, 40), rng.uniform(0, 23, 40)], 1)
    for rec in (clip.reconstruction(), clip.reconstruction(window=6, overlap=2)):
        targets = observation_frames(rec.windows, starts[:, 0].astype(int), 4)
        targets[0, 1] = -1
        seen = rec.observe(starts, targets)
        whole = rec.tracks(starts, frame="world")
        rows, cols = np.nonzero(targets >= 0)
        assert seen.points.shape == (40, 4, 3) and np.isnan(seen.points[0, 1]).all() and seen.visibility[0, 1] == 0
        scale = np.abs(whole.points[np.isfinite(whole.points)]).max()
        np.testing.assert_allclose(seen.points[rows, cols], whole.points[rows, targets[rows, cols]], atol=1e-6 * scale)
        np.testing.assert_allclose(seen.uv[rows, cols], whole.uv[rows, targets[rows, cols]], atol=1e-9)
        assert np.array_equal(seen.visibility[rows, cols], whole.visibility[rows, targets[rows, cols]])
    with pytest.raises(UserError, match="window of their source frame"):
        rec.observe(starts[:1] * [0, 1, 1], np.array([[0, 11]]))


def test_observation_frames_spread_over_the_window_with_the_source_among_them():
    from d4rt.io.output_plan import observation_frames

    windows = plan_windows(30, 12, 3)
    sources = np.arange(30)
    frames = observation_frames(windows, sources, 5)
    assert frames.shape == (30, 5)
    for s, row in zip(sources, frames):
        a, b = next(w for w in windows if w[0] <= s < w[1])  # the first window holding it owns it
        assert s in row and len(set(row)) == 5 and row.min() >= a and row.max() < b
    assert (observation_frames([(0, 3)], np.array([1]), 5) == [[0, 1, 2, -1, -1]]).all()


def test_adjacent_pose_pairs_are_exact_and_chain_across_windows():
    """pose_pairs="adjacent" fits frame i against frame i - 1 and chains the fits: on the oracle it gives the
    paper's poses, in one window and stitched over three (where a window's chain starts at its first frame)."""
    clip = render_clip(8, 24, 32, 48, environment="room", num_objects=5, camera_motion="orbit", moving_fraction=0.8)
    gt = invert_rigid(clip.cam_to_world[0]) @ clip.cam_to_world
    scale = np.linalg.norm(gt[:, :3, 3], axis=1).max() + 1.0
    for options in ({}, {"window": 8, "overlap": 3}):
        rec = clip.reconstruction(pose_pairs="adjacent", **options)
        cams = rec.cameras()
        assert rotation_error_deg(cams.cam_to_world, gt).max() < 0.01
        assert np.abs(cams.cam_to_world[:, :3, 3] - gt[:, :3, 3]).max() < 1e-4 * scale
        paper = clip.reconstruction(**options).cameras()
        assert np.allclose(cams.intrinsics, paper.intrinsics)  # the same frame-i answers serve the intrinsics
        assert np.abs(cams.cam_to_world - paper.cam_to_world).max() < 1e-4 * scale
    with pytest.raises(UserError, match="pose_pairs must be one of first, adjacent, graph"):
        clip.reconstruction(pose_pairs="previous")

    class Recording:  # the oracle, keeping every query it is asked
        num_frames = clip.num_frames

        def __init__(self):
            self.asked = []

        def query(self, queries):
            self.asked.append(np.array(queries))
            return clip.oracle.query(queries)

    gaps = {}
    for pairs in ("first", "adjacent"):
        answerer = Recording()
        Reconstruction(answerer, clip.rgb, pose_pairs=pairs).cameras()
        asked = np.concatenate(answerer.asked)
        gaps[pairs] = np.abs(asked[:, 2] - asked[:, 4]).max()
        assert len(asked) == 2 * clip.num_frames * 12 * 12  # the same cost: two queries per grid point and frame
    assert gaps == {"first": clip.num_frames - 1, "adjacent": 1}

    # A model carries its own pairing (config pose_pairs, chosen per model): from_model uses it unless told.
    for own in ("first", "adjacent"):
        model = SimpleNamespace(config=D4RTConfig.preset("tiny", pose_pairs=own), encode=lambda rgb: Recording())
        assert Reconstruction.from_model(model, clip.rgb).pose_pairs == own
        assert Reconstruction.from_model(model, clip.rgb, pose_pairs="first").pose_pairs == "first"
    assert D4RTConfig.from_json(D4RTConfig.preset("tiny", pose_pairs="adjacent").to_json()).pose_pairs == "adjacent"
    with pytest.raises(UserError, match="config pose_pairs must be one of first, adjacent, graph"):
        D4RTConfig.preset("tiny", pose_pairs="previous")


def test_graph_pose_pairs_are_exact_and_ask_the_gaps_inside_each_window():
    """pose_pairs="graph" fits frame i against i - 1, i - 2, i - 4, ... and solves all poses at once: exact on the
    oracle in one window and over three (where gaps 8 and 16 do not fit), asking only the gaps that fit."""
    clip = render_clip(8, 24, 32, 48, environment="room", num_objects=5, camera_motion="orbit", moving_fraction=0.8)
    gt = invert_rigid(clip.cam_to_world[0]) @ clip.cam_to_world
    scale = np.linalg.norm(gt[:, :3, 3], axis=1).max() + 1.0
    for options in ({}, {"window": 8, "overlap": 3}):
        cams = clip.reconstruction(pose_pairs="graph", **options).cameras()
        assert rotation_error_deg(cams.cam_to_world, gt).max() < 0.01
        assert np.abs(cams.cam_to_world[:, :3, 3] - gt[:, :3, 3]).max() < 1e-4 * scale

    asked = []

    class Recording:  # the oracle, keeping every query it is asked
        num_frames = clip.num_frames

        def query(self, queries):
            asked.append(np.array(queries))
            return clip.oracle.query(queries)

    # A one-frame video has no fit to make: its camera is the world.
    single = render_clip(8, 1, 32, 48, environment="room")
    assert np.array_equal(single.reconstruction(pose_pairs="graph").cameras().cam_to_world, np.eye(4)[None])
    # Per frame one query per grid point in its own camera and one per gap that fits, always an earlier camera.
    Reconstruction(Recording(), clip.rgb, pose_pairs="graph").cameras()
    queries = np.concatenate(asked)
    assert set(np.abs(queries[:, 2] - queries[:, 4]).astype(int)) == {0, 1, 2, 4, 8, 16}
    assert (queries[:, 4] <= queries[:, 2]).all()
    fitting = sum(1 + sum(i - g >= 0 for g in (1, 2, 4, 8, 16)) for i in range(clip.num_frames))
    assert len(np.concatenate(asked)) == fitting * 12 * 12


def test_pose_graph_averages_inconsistent_fits_and_names_a_frame_left_out():
    """With noisy relative fits the solution is a set of proper rigid poses closer to the truth than the chain
    of adjacent fits alone; a chain alone gives the chained poses; a frame no fit reaches is a UserError."""
    from d4rt.geometry.transforms import invert_rigid as inv
    from d4rt.reconstruction.cameras import pose_graph

    rng = np.random.default_rng(0)
    t = 16
    truth = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
    for i in range(1, t):
        step = np.eye(4)
        step[:3, :3] = torch.linalg.matrix_exp(torch.tensor(_skew(rng.normal(0, 0.05, 3)))).numpy()
        step[:3, 3] = rng.normal(0, 0.1, 3) + [0.2, 0, 0]
        truth[i] = truth[i - 1] @ step

    def fit(i, j, noise):  # camera i -> camera j, with a random rotation error of about ``noise`` radians
        exact = inv(truth[j]) @ truth[i]
        wobble = np.eye(4)
        wobble[:3, :3] = torch.linalg.matrix_exp(torch.tensor(_skew(rng.normal(0, noise, 3)))).numpy()
        wobble[:3, 3] = rng.normal(0, noise, 3)
        return wobble @ exact

    chain_edges = np.array([(i, i - 1) for i in range(1, t)])
    exact = pose_graph(t, chain_edges, np.stack([inv(truth[j]) @ truth[i] for i, j in chain_edges]))
    assert np.abs(exact - truth).max() < 1e-9
    edges = np.array([(i, i - g) for g in (1, 2, 4, 8) for i in range(g, t)])
    fits = np.stack([fit(i, j, 0.02) for i, j in edges])
    chained = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
    for i in range(1, t):
        chained[i] = chained[i - 1] @ fits[i - 1]  # the first t - 1 edges are the adjacent ones
    graph = pose_graph(t, edges, fits)
    rotations = graph[:, :3, :3]
    assert np.allclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(rotations), 1.0)
    error = lambda poses: np.linalg.norm(poses[:, :3, 3] - truth[:, :3, 3], axis=1).mean()
    assert error(graph) < 0.6 * error(chained)
    assert np.array_equal(pose_graph(1, np.zeros((0, 2)), np.zeros((0, 4, 4))), np.eye(4)[None])
    with pytest.raises(UserError, match="not every one of the 4 frames is joined to frame 0"):
        pose_graph(4, np.array([(1, 0), (3, 2)]), np.stack([np.eye(4)] * 2))


def _skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
