"""Moving-object masks (Reconstruction.motion_masks) on the exact oracle, against motion computed from the clip's own
arrays (depth, object ids, camera and body poses), with no query involved."""

import numpy as np
import pytest

from d4rt.errors import UserError
from d4rt.geometry.camera import unproject_depth
from d4rt.geometry.transforms import apply_transform
from d4rt.reconstruction import MotionMasks, Reconstruction
from d4rt.reconstruction.motion import target_frames
from d4rt.synthetic import render_clip


def motion_from_arrays(clip, compared: np.ndarray) -> np.ndarray:
    """(T, H, W): the largest distance each pixel's surface point travels in the world between its frame and the
    frames in ``compared`` (T, K), over its depth; NaN where the clip has no depth."""
    t, h, w = clip.depth.shape
    out = np.full((t, h, w), np.nan)
    for i in range(t):
        world = apply_transform(clip.cam_to_world[i], unproject_depth(clip.depth[i].astype(np.float64),
                                                                      clip.intrinsics[i]))
        ids = clip.object_ids[i].astype(np.int64)
        local = np.linalg.inv(clip.object_to_world[i])[ids]  # (H, W, 4, 4): world -> the pixel's body
        travel = np.zeros((h, w))
        for j in compared[i]:
            move = clip.object_to_world[j][ids] @ local
            there = np.einsum("hwij,hwj->hwi", move[..., :3, :3], world) + move[..., :3, 3]
            travel = np.maximum(travel, np.linalg.norm(there - world, axis=-1))
        ok = np.isfinite(clip.depth[i]) & (clip.depth[i] > 0)
        out[i][ok] = travel[ok] / clip.depth[i][ok]
    return out


def moving_bodies(clip) -> list[int]:
    return [k for k, kind in enumerate(clip.scene.info["body_motion"]) if kind not in ("environment", "static")]


@pytest.mark.parametrize("window", [None, 5])
def test_masks_equal_the_motion_of_the_clips_bodies(room_clip, window):
    rec = Reconstruction.from_clip(room_clip, window=window, overlap=2 if window else None)
    masks = rec.motion_masks(threshold=0.05)
    assert isinstance(masks, MotionMasks) and masks.relative_motion.shape == room_clip.depth.shape
    assert masks.dynamic.shape == room_clip.depth.shape and masks.dynamic.dtype == bool
    truth = motion_from_arrays(room_clip, masks.target_frames)
    ok = np.isfinite(truth)
    assert (np.isfinite(masks.relative_motion) == ok).all()
    assert np.abs(masks.relative_motion[ok] - truth[ok]).max() < 1e-5
    assert (masks.dynamic == (np.nan_to_num(truth) > 0.05)).all()
    # The premise: the arm and some objects move, the environment never does.
    assert masks.dynamic.any() and not masks.dynamic[room_clip.object_ids == 0].any()
    assert np.isin(room_clip.object_ids[masks.dynamic], moving_bodies(room_clip)).all()
    if window:  # each frame is compared with frames of the window that owns it
        starts = [a for a, _ in rec.windows]
        assert masks.target_frames[0].tolist() == target_frames(*rec.windows[0], 5).tolist()
        assert masks.target_frames[-1][0] == starts[-1] and masks.target_frames[-1][-1] == room_clip.num_frames - 1


def test_a_moving_camera_alone_moves_nothing():
    clip = render_clip(21, 8, 32, 40, environment="outdoor", num_objects=4, camera_motion="handheld", shake=True,
                       moving_fraction=0.0, articulated=False)
    masks = clip.reconstruction().motion_masks(resolution=(16, 20))
    surface = np.isfinite(masks.relative_motion)
    assert surface.mean() > 0.9 and np.nanmax(masks.relative_motion) < 1e-5 and not masks.dynamic.any()
    assert masks.threshold == 0.05


def test_every_moving_body_in_view_is_found(outdoor_clip):
    masks = outdoor_clip.reconstruction().motion_masks(threshold=1e-3)
    for k in moving_bodies(outdoor_clip):
        seen = outdoor_clip.object_ids == k
        if seen.any():
            assert masks.dynamic[seen].mean() > 0.9, k


def test_target_frames_span_the_window():
    assert target_frames(0, 24, 5).tolist() == [0, 6, 12, 17, 23]
    assert target_frames(10, 13, 5).tolist() == [10, 11, 12]


@pytest.mark.parametrize("options, message", [({"threshold": 0}, "threshold must be a finite number > 0"),
                                               ({"threshold": float("nan")}, "threshold must be a finite number > 0"),
                                               ({"targets": 1}, "target frames must be an integer >= 2"),
                                               ({"resolution": (0, 4)}, "resolution must be")])
def test_bad_options_are_one_line_errors(room_clip, options, message):
    with pytest.raises(UserError, match=message) as error:
        room_clip.reconstruction().motion_masks(**options)
    assert "\n" not in str(error.value)
