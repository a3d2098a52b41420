"""Shot cuts: found at the junction of two different clips, not inside one clip or in the real frames."""

from importlib.resources import files
from pathlib import Path

import numpy as np

from d4rt.io.frames import load_frames
from d4rt.io.shots import detect_cuts, frame_differences, shot_ranges
from d4rt.synthetic import render_clip

TUM = Path(str(files("d4rt") / "assets" / "tum-fr3-long-office-household" / "rgb"))


def test_a_cut_between_two_clips_is_found_and_nothing_inside_them():
    first = render_clip(11, 7, 36, 48, environment="room", camera_motion="handheld", num_objects=4).rgb
    second = render_clip(12, 5, 36, 48, environment="outdoor", camera_motion="pan", num_objects=3).rgb
    assert detect_cuts(first) == [] and detect_cuts(second) == []
    video = np.concatenate([first, second])
    assert detect_cuts(video) == [7]
    assert shot_ranges(len(video), [7]) == [(0, 7), (7, 12)] and shot_ranges(4, []) == [(0, 4)]
    assert detect_cuts(video, threshold=0.99) == []  # configurable


def test_real_frames_with_camera_motion_are_one_shot():
    rgb = load_frames(TUM).rgb
    assert frame_differences(rgb).max() > 0.2  # the camera moves a lot between these frames...
    assert detect_cuts(rgb) == []  # ...but steadily: no spike
