"""The oracle against the rendered ground truth and against the rules of rigid motion."""

import numpy as np
import pytest
import torch

from d4rt.geometry.camera import project, unproject_depth
from d4rt.geometry.transforms import apply_transform, invert_rigid
from tests.conftest import pixel_centre_queries, random_queries


def test_unprojected_depth_equals_oracle_point(clip):
    """t_src = t_tgt = t_cam: the oracle's point is the rendered depth unprojected, to float precision."""
    frames = [0, clip.num_frames // 2, clip.num_frames - 1]
    out = clip.oracle.query(pixel_centre_queries(clip, frames))
    expected = unproject_depth(clip.depth[frames].astype(np.float64), clip.intrinsics[frames]).reshape(-1, 3)
    points = out["points"].numpy()
    assert out["valid"].all()
    err = np.abs(points - expected).max(1) / expected[:, 2]
    # Rendered depth is stored in float32: typically exact to its rounding, a few ulps at grazing angles.
    assert np.median(err) < 1e-7 and err.max() < 4e-6, (np.median(err), err.max())
    # Object ids and normals agree too.
    assert np.array_equal(out["object_id"].numpy(), clip.object_ids[frames].reshape(-1))
    normals = clip.normals[frames].reshape(-1, 3).astype(np.float64)
    assert np.abs(out["normals"].numpy() - normals).max() < 1e-4
    # The point projects back to the pixel it came from, and it is visible there.
    assert out["visibility"].all()
    q = pixel_centre_queries(clip, frames)
    assert np.abs(out["uv"].numpy() - q[:, :2]).max() < 1e-9


def test_same_point_in_other_camera_is_a_rigid_change_of_frame(clip):
    """t_tgt = t_src, any t_cam: the point is the world point seen from camera t_cam."""
    f_src, f_cam = 1, clip.num_frames - 2
    out = clip.oracle.query(pixel_centre_queries(clip, [f_src], t_tgt=f_src, t_cam=f_cam))
    cam = unproject_depth(clip.depth[f_src].astype(np.float64), clip.intrinsics[f_src]).reshape(-1, 3)
    world = apply_transform(clip.cam_to_world[f_src], cam)
    expected = apply_transform(invert_rigid(clip.cam_to_world[f_cam]), world)
    assert np.abs(out["points"].numpy() - expected).max() < 2e-5 * np.abs(expected).max()
    assert np.abs(out["motion"].numpy()).max() < 1e-9  # no time passes


def test_static_points_keep_their_world_position(clip):
    rng = np.random.default_rng(0)
    q = random_queries(rng, clip, 4000)
    out = clip.oracle.query(q)
    obj = out["object_id"].numpy()
    static_ids = [k for k, kind in enumerate(clip.scene.info["body_motion"]) if kind in ("environment", "static")]
    static = np.isin(obj, static_ids)
    assert static.sum() > 500
    t_cam = q[:, 4].astype(int)
    world_tgt = apply_transform(clip.cam_to_world[t_cam], out["points"].numpy())
    src = clip.oracle.query(np.concatenate([q[:, :3], q[:, 2:3], q[:, 2:3]], 1))
    world_src = apply_transform(clip.cam_to_world[q[:, 2].astype(int)], src["points"].numpy())
    scale = np.abs(world_src).max()
    assert np.abs(world_tgt - world_src)[static].max() < 1e-9 * scale
    # ...and moving bodies do move in the world.
    moving = ~static & (q[:, 2] != q[:, 3])
    assert np.linalg.norm(world_tgt - world_src, axis=1)[moving].mean() > 1e-3


def test_rigid_bodies_preserve_distances_over_time(room_clip):
    clip = room_clip
    oracle = clip.oracle
    moving_ids = [k for k, kind in enumerate(clip.scene.info["body_motion"]) if kind not in ("environment", "static")]
    assert moving_ids
    checked = 0
    for k in moving_ids:
        ys, xs = np.nonzero(clip.object_ids[0] == k)
        if len(ys) < 2:
            continue
        a, b = 0, len(ys) - 1
        for t in range(clip.num_frames):
            q = np.array([[(xs[i] + 0.5) / clip.width, (ys[i] + 0.5) / clip.height, 0, t, 0] for i in (a, b)])
            p = oracle.query(q)["points"].numpy()
            d = np.linalg.norm(p[0] - p[1])
            if t == 0:
                d0 = d
            assert abs(d - d0) < 1e-9 * max(1.0, d0)
        checked += 1
    assert checked >= 2


def test_motion_is_displacement_in_camera_t_cam(clip):
    rng = np.random.default_rng(1)
    q = random_queries(rng, clip, 2000)
    out = clip.oracle.query(q)
    at_src = clip.oracle.query(np.concatenate([q[:, :2], q[:, 2:3], q[:, 2:3], q[:, 4:5]], 1))
    assert np.allclose(out["motion"].numpy(), out["points"].numpy() - at_src["points"].numpy(), atol=1e-9)


def test_uv_is_the_projection_into_frame_t_tgt(clip):
    rng = np.random.default_rng(2)
    q = random_queries(rng, clip, 2000)
    q[:, 4] = q[:, 3]  # express the point in camera t_tgt: uv must be its projection with K[t_tgt]
    out = clip.oracle.query(q)
    xy, z = project(out["points"].numpy(), clip.intrinsics[q[:, 3].astype(int)])
    uv = np.stack([(xy[:, 0] + 0.5) / clip.width, (xy[:, 1] + 0.5) / clip.height], 1)
    front = z > 0
    assert np.array_equal(out["uv_valid"].numpy(), front)
    assert np.abs(out["uv"].numpy()[front] - uv[front]).max() < 1e-9


def test_visibility_agrees_with_rendered_frames(clip):
    """Where the oracle says visible, the rendered frame t_tgt shows the same body at that depth around
    the projected point; where it says occluded, something nearer is rendered there. Points whose
    surrounding 2x2 pixel centres show more than one body or a crease are skipped, and must be few."""
    rng = np.random.default_rng(3)
    q = random_queries(rng, clip, 12000)
    out = clip.oracle.query(q)
    t_tgt = q[:, 3].astype(int)
    q_cam = q.copy()
    q_cam[:, 4] = q[:, 3]
    z = clip.oracle.query(q_cam)["points"].numpy()[:, 2]
    uv = out["uv"].numpy()
    inside = out["uv_valid"].numpy() & np.all((uv >= 0) & (uv <= 1), 1)
    visible = out["visibility"].numpy() > 0.5
    assert not (visible & ~inside).any()
    x, y = uv[:, 0] * clip.width - 0.5, uv[:, 1] * clip.height - 0.5
    # Only points surrounded by four pixel centres (not in the outer half-pixel border) are checked.
    inner = inside & (x >= 0) & (x < clip.width - 1) & (y >= 0) & (y < clip.height - 1)
    counts = {"visible": 0, "occluded": 0, "edge": 0}
    for i in np.nonzero(inner)[0]:
        c0, r0 = int(np.floor(x[i])), int(np.floor(y[i]))
        rows, cols = [r0, r0 + 1], [c0, c0 + 1]
        ids = clip.object_ids[t_tgt[i]][np.ix_(rows, cols)]
        depth = clip.depth[t_tgt[i]][np.ix_(rows, cols)]
        normals = clip.normals[t_tgt[i]][np.ix_(rows, cols)].reshape(4, 3)
        if (ids != ids[0, 0]).any() or (normals @ normals[0]).min() < 0.99:  # an edge or a crease
            counts["edge"] += 1
            continue
        if visible[i]:
            # Between pixel centres the surface's depth lies within its corners' (1% for curvature).
            assert ids[0, 0] == out["object_id"][i]
            assert depth.min() * 0.99 <= z[i] <= depth.max() * 1.01, (i, depth, z[i])
            counts["visible"] += 1
        else:
            # Something nearer is rendered there (same 1% interpolation allowance: an occluder may touch
            # the point, e.g. where the parts of the articulated arm meet).
            assert depth.min() < z[i] and depth.max() < z[i] * 1.01, (i, depth, z[i])
            counts["occluded"] += 1
    assert counts["visible"] > 2000 and counts["occluded"] > 40, counts
    assert counts["edge"] < 0.3 * inner.sum(), counts


def test_normals_are_unit_and_match_depth_gradients(clip):
    n = clip.normals.astype(np.float64)
    assert np.abs(np.linalg.norm(n, axis=-1) - 1).max() < 1e-5
    pts = unproject_depth(clip.depth.astype(np.float64), clip.intrinsics)
    dx = pts[:, 1:-1, 2:] - pts[:, 1:-1, :-2]
    dy = pts[:, 2:, 1:-1] - pts[:, :-2, 1:-1]
    fd = np.cross(dy, dx)  # x right, y down: this order faces the camera
    fd /= np.linalg.norm(fd, axis=-1, keepdims=True)
    ids = clip.object_ids.astype(int)
    same = np.ones_like(ids[:, 1:-1, 1:-1], dtype=bool)
    for dy_, dx_ in [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)]:
        same &= ids[:, 1 + dy_:ids.shape[1] - 1 + dy_, 1 + dx_:ids.shape[2] - 1 + dx_] == ids[:, 1:-1, 1:-1]
    inner = n[:, 1:-1, 1:-1]
    # Away from edges and creases (normals of all neighbours nearly equal) the two must agree.
    smooth = same & (np.einsum("thwc,thwc->thw", inner, n[:, :-2, 1:-1]) > 0.999) \
        & (np.einsum("thwc,thwc->thw", inner, n[:, 2:, 1:-1]) > 0.999) \
        & (np.einsum("thwc,thwc->thw", inner, n[:, 1:-1, :-2]) > 0.999) \
        & (np.einsum("thwc,thwc->thw", inner, n[:, 1:-1, 2:]) > 0.999)
    cos = np.einsum("thwc,thwc->thw", fd, inner)[smooth]
    assert smooth.sum() > 0.5 * smooth.size
    assert np.percentile(cos, 1) > 0.999 and cos.min() > 0.99
    # Normals face the camera.
    view = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    assert (np.einsum("thwc,thwc->thw", view, n) < 0).all()


def test_float32_queries_give_float32_answers(room_clip):
    q = torch.tensor([[0.5, 0.5, 0, 1, 2]], dtype=torch.float32)
    out = room_clip.oracle.query(q)
    assert out["points"].dtype == torch.float32 and out["points"].shape == (1, 3)
    assert out["uv"].shape == (1, 2) and out["visibility"].shape == (1,) and out["valid"].dtype == torch.bool


@pytest.mark.parametrize("bad, message", [
    (np.zeros((3, 4)), "shape"),
    (np.array([[1.2, 0.5, 0, 0, 0]]), "outside [0, 1]"),
    (np.array([[0.5, -0.1, 0, 0, 0]]), "outside [0, 1]"),
    (np.array([[0.5, 0.5, 0, 8, 0]]), "t_tgt"),
    (np.array([[0.5, 0.5, 0.5, 0, 0]]), "t_src"),
    (np.array([[0.5, 0.5, 0, 0, -1]]), "t_cam"),
    (np.array([[np.nan, 0.5, 0, 0, 0]]), "NaN"),
])
def test_bad_queries_raise_one_clear_error(room_clip, bad, message):
    from d4rt.errors import UserError

    with pytest.raises(UserError, match=message.replace("[", r"\[").replace("]", r"\]")):
        room_clip.oracle.query(bad)
