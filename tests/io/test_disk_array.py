"""Arrays on disk (DiskArray) index like numpy arrays, and .npz files written block by block read back
as np.savez_compressed's do."""

import numpy as np
import pytest

from d4rt.disk_array import DiskArray, frame_blocks, row_range
from d4rt.io.npz_stream import write_npz


@pytest.fixture
def pair(tmp_path):
    reference = np.random.default_rng(0).integers(0, 255, (7, 5, 4, 3)).astype(np.uint8)
    array = DiskArray.create(tmp_path / "a.raw", reference.shape, np.uint8)
    array[0:7] = reference
    return reference, array


def test_indexing_matches_numpy(pair):
    reference, array = pair
    rng = np.random.default_rng(1)
    f, y, x = rng.integers(0, 7, 50), rng.integers(0, 5, 50), rng.integers(0, 4, 50)
    keys = [3, -1, np.int64(2), slice(None), slice(2, 5), slice(1, None, 3), slice(-3, None), slice(5, 2),
            np.array([4, 0, 4, 6]), [1, 2], np.arange(7) % 2 == 0, (2, slice(1, 3)), (slice(1, 4), 0),
            (f, y, x), (np.array([[1, 2], [3, 1]]), 0, 1)]
    for key in keys:
        np.testing.assert_array_equal(array[key], reference[key], err_msg=repr(key))
    np.testing.assert_array_equal(np.asarray(array), reference)
    np.testing.assert_array_equal(np.stack(list(array)), reference)
    assert (array.shape, array.dtype, array.ndim, len(array), array.nbytes) == (
        reference.shape, reference.dtype, 4, 7, reference.nbytes)
    with pytest.raises(IndexError):
        array[7]
    with pytest.raises(IndexError):
        array[np.array([0, 9])]


def test_writes_appends_and_row_views(tmp_path, pair):
    reference, array = pair
    array[2] = 9
    reference[2] = 9
    np.testing.assert_array_equal(np.asarray(array), reference)
    view = row_range(array, 2, 5)
    assert isinstance(view, DiskArray) and view.shape == (3, 5, 4, 3)
    np.testing.assert_array_equal(np.asarray(view), reference[2:5])
    np.testing.assert_array_equal(row_range(reference, 2, 5), reference[2:5])
    grow = DiskArray.growable(tmp_path / "g.raw", (2,), np.float32)
    grow.append(np.ones((3, 2)))
    grow.append(np.arange(4).reshape(2, 2))
    np.testing.assert_array_equal(np.asarray(grow), np.concatenate([np.ones((3, 2)), np.arange(4).reshape(2, 2)]))
    with pytest.raises(ValueError):
        grow.append(np.ones((1, 3)))


def test_npy_file_read_in_place(tmp_path):
    reference = np.arange(2 * 3 * 4, dtype=np.float64).reshape(2, 3, 4)
    np.save(tmp_path / "x.npy", reference)
    array = DiskArray.open_npy(tmp_path / "x.npy")
    assert array.shape == reference.shape and array.dtype == reference.dtype and not array.writable
    np.testing.assert_array_equal(array[1], reference[1])
    with pytest.raises(PermissionError):
        array[0] = 0


def test_frame_blocks_cover_every_row_once():
    array = np.zeros((10, 100, 100, 3), np.uint8)  # 30 kB a frame
    runs = list(frame_blocks(array, bytes_per_block=70_000))
    assert runs == [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    assert list(frame_blocks(array, frames_per_block=4)) == [(0, 4), (4, 8), (8, 10)]


def test_streamed_npz_reads_back_like_savez_compressed(tmp_path, pair):
    reference, array = pair
    arrays = {"frames": reference, "scalar": np.float64(2.5), "empty": np.zeros((0, 3), np.float32),
              "ints": np.arange(5, dtype=np.int64), "strings": np.array(["a", "bc"])}
    np.savez_compressed(tmp_path / "ref.npz", **arrays)
    write_npz(tmp_path / "new.npz", {**arrays, "frames": array})
    with np.load(tmp_path / "ref.npz") as ref, np.load(tmp_path / "new.npz") as new:
        assert sorted(ref.files) == sorted(new.files)
        for key in ref.files:
            assert ref[key].dtype == new[key].dtype and ref[key].shape == new[key].shape, key
            np.testing.assert_array_equal(ref[key], new[key])
