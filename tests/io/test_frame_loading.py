"""Reading frames from video files, image folders and arrays, and every way a source can be unusable."""

import numpy as np
import pytest
from PIL import Image

from d4rt.errors import UserError
from d4rt.io.frames import FrameRange, load_frames
from d4rt.io.video import write_video


@pytest.fixture(scope="module")
def frames():
    """12 frames whose mean brightness encodes the frame index (survives lossy video coding)."""
    levels = np.linspace(20, 230, 12).round().astype(np.uint8)
    rgb = np.repeat(levels[:, None, None, None], 3, axis=-1) * np.ones((1, 24, 32, 3), np.uint8)
    rgb[:, :8, :8] = [255, 0, 0]
    return rgb


def _brightness_index(rgb, levels):
    return [int(np.argmin(np.abs(levels - f[12:, 12:].mean()))) for f in rgb]


def test_video_file_with_range_stride_and_cap(tmp_path, frames):
    path = write_video(tmp_path / "clip.mp4", frames, fps=12)
    levels = frames[:, 12:, 12:].mean(axis=(1, 2, 3))
    whole = load_frames(path)
    assert whole.rgb.shape == (12, 24, 32, 3) and whole.rgb.dtype == np.uint8
    assert _brightness_index(whole.rgb, levels) == list(range(12))
    np.testing.assert_allclose(whole.timestamps, np.arange(12) / 12, atol=1e-6)
    assert whole.fps == pytest.approx(12)
    part = load_frames(path, FrameRange(start=2, end=11, stride=3))
    assert list(part.indices) == [2, 5, 8] and _brightness_index(part.rgb, levels) == [2, 5, 8]
    assert part.fps == pytest.approx(4)
    capped = load_frames(path, FrameRange(start=1, max_frames=4))
    assert list(capped.indices) == [1, 2, 3, 4] and _brightness_index(capped.rgb, levels) == [1, 2, 3, 4]


def test_image_folder_in_natural_order_with_time_stamps(tmp_path, frames):
    named = tmp_path / "named"
    named.mkdir()
    for i in range(11):  # img2 must come before img10
        Image.fromarray(frames[i]).save(named / f"img{i}.png")
    (named / "notes.txt").write_text("not an image")
    out = load_frames(named, FrameRange(stride=2))
    assert list(out.indices) == [0, 2, 4, 6, 8, 10]
    np.testing.assert_array_equal(out.rgb, frames[[0, 2, 4, 6, 8, 10]])  # PNG is lossless
    assert out.fps is None and list(out.timestamps) == [0, 2, 4, 6, 8, 10]

    stamped = tmp_path / "stamped"  # TUM RGB-D layout: file names are capture times
    stamped.mkdir()
    for i in range(4):
        Image.fromarray(frames[i]).save(stamped / f"{1341847980.5 + 0.25 * i:.6f}.png")
    out = load_frames(stamped)
    np.testing.assert_allclose(out.timestamps - out.timestamps[0], [0, 0.25, 0.5, 0.75], atol=1e-6)
    assert out.fps == pytest.approx(4)


def test_arrays(tmp_path, frames):
    np.save(tmp_path / "v.npy", frames)
    np.testing.assert_array_equal(load_frames(tmp_path / "v.npy").rgb, frames)
    np.savez(tmp_path / "clip.npz", rgb=frames, depth=np.zeros(frames.shape[:3]))
    np.testing.assert_array_equal(load_frames(tmp_path / "clip.npz", FrameRange(end=3)).rgb, frames[:3])
    np.savez(tmp_path / "one.npz", anything=frames.astype(np.float32) / 255)
    np.testing.assert_array_equal(load_frames(tmp_path / "one.npz").rgb, frames)


def _write(path, data: bytes):
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("make, message", [
    (lambda d: d / "missing.mp4", "does not exist"),
    (lambda d: _write(d / "empty.mp4", b""), "is empty"),
    (lambda d: _write(d / "corrupt.mp4", b"not a video at all" * 50), "cannot decode video"),
    (lambda d: _write(d / "notes.txt", b"hello"), "unsupported input type '.txt'"),
    (lambda d: _write(d / "corrupt.npz", b"PK garbage"), "cannot read array file"),
    (lambda d: np.save(d / "flat.npy", np.zeros((4, 5))) or d / "flat.npy", "expected frames (T, H, W, 3)"),
    (lambda d: (d / "nothing").mkdir() or d / "nothing", "no images"),
])
def test_unusable_sources_name_the_problem(tmp_path, make, message):
    path = make(tmp_path)
    with pytest.raises(UserError, match=message.replace("(", r"\(").replace(")", r"\)")) as err:
        load_frames(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_mixed_sizes_corrupt_images_and_too_few_frames(tmp_path, frames):
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    Image.fromarray(frames[0]).save(mixed / "a.png")
    Image.fromarray(frames[1][:, :16]).save(mixed / "b.png")
    with pytest.raises(UserError, match="mixed sizes: b.png is 16x24 but a.png is 32x24"):
        load_frames(mixed)
    broken = tmp_path / "broken"
    broken.mkdir()
    Image.fromarray(frames[0]).save(broken / "a.png")
    (broken / "b.png").write_bytes(b"\x89PNG truncated")
    with pytest.raises(UserError, match="cannot read image .*b.png"):
        load_frames(broken)
    np.save(tmp_path / "v.npy", frames)
    with pytest.raises(UserError, match=r"gives 1 frame\(s\) \(start 11.*at least 2 are needed"):
        load_frames(tmp_path / "v.npy", FrameRange(start=11))
    for bad in (dict(start=-1), dict(start=3, end=3), dict(stride=0), dict(max_frames=0)):
        with pytest.raises(UserError):
            FrameRange(**bad)


def test_spooled_frames_equal_the_loaded_ones_for_every_source(tmp_path, frames):
    """load_frames(..., spool=DIR): the same frames, indices and times, held on disk (a DiskArray read a
    few frames at a time) for every kind of source and selection; a consecutive uint8 .npy is read in place."""
    from d4rt.disk_array import DiskArray

    folder = tmp_path / "images"
    folder.mkdir()
    for i, frame in enumerate(frames):
        Image.fromarray(frame).save(folder / f"{i}.png")
    np.save(tmp_path / "clip.npy", frames)
    np.save(tmp_path / "float.npy", frames.astype(np.float32) / 255)
    np.savez_compressed(tmp_path / "clip.npz", rgb=frames)
    sources = [write_video(tmp_path / "clip.mp4", frames, fps=12), folder, tmp_path / "clip.npy",
               tmp_path / "float.npy", tmp_path / "clip.npz"]
    for source in sources:
        for selection in (FrameRange(), FrameRange(start=2, end=11, stride=3), FrameRange(start=1, max_frames=4)):
            spool = tmp_path / f"spool-{source.name}-{selection.start}-{selection.stride}"
            spool.mkdir()
            eager, lazy = load_frames(source, selection), load_frames(source, selection, spool=spool)
            assert isinstance(lazy.rgb, DiskArray), source
            np.testing.assert_array_equal(np.asarray(lazy.rgb), eager.rgb, err_msg=str(source))
            np.testing.assert_array_equal(lazy.indices, eager.indices)
            np.testing.assert_array_equal(lazy.timestamps, eager.timestamps)
            assert lazy.fps == eager.fps
            in_place = source.name == "clip.npy" and selection.stride == 1
            assert (lazy.rgb.path == source) == in_place and (not any(spool.iterdir())) == in_place
