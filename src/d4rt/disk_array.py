"""Arrays that live in a file and are read a few rows at a time, so that what a long video produces (its
frames, depth maps, point cloud) does not have to fit in memory at once.

A :class:`DiskArray` is a C-ordered array of fixed dtype stored raw in a file (from ``offset`` on: an
.npy file's data can be read in place). Indexing it along its first axis returns ordinary numpy arrays
with numpy's semantics; only the rows asked for are read (with ``os.pread``, not a memory map, so pages
read once count as the system's file cache, not as this process's memory). Rows can be written
(``array[a:b] = rows``) and a growable array takes ``append``. ``np.asarray(array)`` reads it whole (what
a caller that needs every value at once gets; the exporters avoid it).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

# How much of an array is read (and the exporters hold) at a time: small enough that the temporaries of a
# block (float64 copies, masks, colours) stay tens of MB, and memory freed by one block is reused by the
# next instead of growing the heap; large enough for few, long reads.
BLOCK_BYTES = 2 << 20


class DiskArray:
    """A (N, ...) array in ``path`` from byte ``offset`` on.

    shape: its shape (for a growable array, N grows with ``append``); dtype: numpy dtype (little-endian
    on disk, as .npy files write it). ``create`` makes a new zero-filled file; ``growable`` an empty one
    to append to; ``open_npy`` reads an existing .npy file in place (read-only).
    """

    def __init__(self, path: str | Path, shape: tuple[int, ...], dtype, offset: int = 0, writable: bool = False):
        self.path = Path(path)
        self.dtype = np.dtype(dtype)
        self.shape = tuple(int(s) for s in shape)
        self.offset = int(offset)
        self.row_shape = self.shape[1:]
        self.row_bytes = int(np.prod(self.row_shape, dtype=np.int64)) * self.dtype.itemsize
        self._fd = os.open(self.path, os.O_RDWR if writable else os.O_RDONLY)
        self.writable = writable

    @classmethod
    def create(cls, path: str | Path, shape: tuple[int, ...], dtype) -> "DiskArray":
        """A new array of zeros (a sparse file: no disk is used until rows are written)."""
        with open(path, "wb") as f:
            f.truncate(int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize)
        return cls(path, shape, dtype, writable=True)

    @classmethod
    def growable(cls, path: str | Path, row_shape: tuple[int, ...], dtype) -> "DiskArray":
        """An empty (0, *row_shape) array that ``append`` extends."""
        Path(path).write_bytes(b"")
        return cls(path, (0, *row_shape), dtype, writable=True)

    @classmethod
    def open_npy(cls, path: str | Path) -> "DiskArray":
        """The data of an .npy file, read in place (C order only)."""
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            shape, fortran, dtype = (np.lib.format.read_array_header_1_0(f) if version == (1, 0)
                                     else np.lib.format.read_array_header_2_0(f))
            offset = f.tell()
        if fortran or dtype.hasobject:
            raise ValueError(f"{path}: only C-ordered arrays of plain numbers can be read in place")
        return cls(path, shape, dtype, offset)

    # -- numpy-like surface -----------------------------------------------------------------------

    def __len__(self) -> int:
        return self.shape[0]

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def nbytes(self) -> int:
        return self.size * self.dtype.itemsize

    def __array__(self, dtype=None, copy=None):
        whole = self.read(0, len(self))
        return whole if dtype is None else whole.astype(dtype, copy=False)

    def __iter__(self):
        for start, stop in frame_blocks(self):
            yield from self.read(start, stop)

    def __getitem__(self, key):
        rest = ()
        if isinstance(key, tuple):
            key, rest = key[0], key[1:]
        if isinstance(key, (int, np.integer)):
            index = int(key) + len(self) if key < 0 else int(key)
            if not 0 <= index < len(self):
                raise IndexError(f"index {key} out of range for {len(self)} rows")
            row = self.read(index, index + 1)[0]
            return row[rest] if rest else row
        if isinstance(key, slice):
            start, stop, step = key.indices(len(self))
            rows = self.read(start, stop) if step == 1 else self.take(np.arange(start, stop, step))
            return rows[(slice(None), *rest)] if rest else rows
        index = np.asarray(key)
        if index.dtype == bool:
            index = np.nonzero(index)[0]
        if rest and any(not isinstance(r, slice) for r in rest):  # point lookups: (rows, ys, xs)
            unique, inverse = np.unique(index, return_inverse=True)
            return self.take(unique)[(inverse.reshape(index.shape), *rest)]
        rows = self.take(index)
        return rows[(slice(None), *rest)] if rest else rows

    def __setitem__(self, key, value) -> None:
        if not isinstance(key, slice):
            key = slice(int(key), int(key) + 1)
            value = np.asarray(value)[None]
        start, stop, step = key.indices(len(self))
        if step != 1:
            raise IndexError("rows of a DiskArray are written in contiguous runs (step 1)")
        self.write(start, np.broadcast_to(np.asarray(value, dtype=self.dtype), (stop - start, *self.row_shape)))

    # -- reading and writing rows ------------------------------------------------------------------

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows [start, stop) as a new array."""
        count = max(0, stop - start)
        out = np.empty((count, *self.row_shape), dtype=self.dtype)
        view = memoryview(out.reshape(-1).view(np.uint8)) if out.size else memoryview(b"")
        done, want = 0, count * self.row_bytes
        while done < want:
            got = os.preadv(self._fd, [view[done:]], self.offset + start * self.row_bytes + done)
            if got <= 0:
                raise OSError(f"{self.path}: the file ends before row {stop} of {len(self)}")
            done += got
        return out

    def take(self, index: np.ndarray) -> np.ndarray:
        """Rows at ``index`` (any order, repeats allowed), read run by run of consecutive rows."""
        index = np.asarray(index, dtype=np.int64).reshape(-1)
        if len(index) and (index.min() < -len(self) or index.max() >= len(self)):
            raise IndexError(f"row index out of range for {len(self)} rows")
        index = np.where(index < 0, index + len(self), index)
        order = np.argsort(index, kind="stable")
        wanted = index[order]
        out = np.empty((len(index), *self.row_shape), dtype=self.dtype)
        for a, b in frame_blocks(self):
            lo, hi = np.searchsorted(wanted, [a, b])
            if lo == hi:
                continue
            rows = wanted[lo:hi]
            breaks = np.nonzero(np.diff(rows) != 1)[0] + 1
            if len(breaks) > 8:  # scattered rows (e.g. an even subset): one read of the block, then pick
                out[order[lo:hi]] = self.read(int(rows[0]), int(rows[-1]) + 1)[rows - rows[0]]
                continue
            for run in np.split(np.arange(lo, hi), breaks):
                out[order[run]] = self.read(int(wanted[run[0]]), int(wanted[run[-1]]) + 1)
        return out

    def write(self, start: int, rows: np.ndarray) -> None:
        if not self.writable:
            raise PermissionError(f"{self.path} is opened read-only")
        data = np.ascontiguousarray(rows, dtype=self.dtype)
        if data.shape[1:] != self.row_shape or start < 0 or start + len(data) > len(self):
            raise ValueError(f"rows of shape {data.shape} do not fit at row {start} of {self.shape}")
        os.pwrite(self._fd, data.reshape(-1).view(np.uint8), self.offset + start * self.row_bytes)

    def append(self, rows: np.ndarray) -> None:
        """Add rows at the end (grows the first axis)."""
        data = np.asarray(rows, dtype=self.dtype)
        start = len(self)
        self.shape = (start + len(data), *self.row_shape)
        self.write(start, data)

    def rows(self, start: int, stop: int) -> "DiskArray":
        """Rows [start, stop) as a DiskArray over the same file (nothing is read)."""
        start, stop, _ = slice(start, stop).indices(len(self))
        stop = max(start, stop)
        return DiskArray(self.path, (stop - start, *self.row_shape), self.dtype,
                         self.offset + start * self.row_bytes, self.writable)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __del__(self):
        try:
            self.close()
        except (OSError, AttributeError, TypeError):
            pass

    def __repr__(self) -> str:
        return f"DiskArray({str(self.path)!r}, shape={self.shape}, dtype={self.dtype})"


def frame_blocks(array, frames_per_block: int | None = None, bytes_per_block: int = BLOCK_BYTES):
    """[a, b) runs of rows of ``array`` (numpy or DiskArray) of about ``bytes_per_block`` each (or
    ``frames_per_block`` rows): how the exporters walk a long video's per-frame arrays."""
    if frames_per_block is None:
        row = int(np.prod(array.shape[1:], dtype=np.int64)) * np.dtype(array.dtype).itemsize
        frames_per_block = max(1, bytes_per_block // max(row, 1))
    return ranges(len(array), frames_per_block)


def ranges(count: int, step: int):
    """[a, b) runs of ``step`` (the last one shorter) covering [0, count)."""
    for a in range(0, count, step):
        yield a, min(a + step, count)


def row_range(array, start: int, stop: int):
    """Rows [start, stop) of a numpy array (a view) or of a DiskArray (a DiskArray: nothing is read)."""
    return array.rows(start, stop) if isinstance(array, DiskArray) else array[start:stop]
