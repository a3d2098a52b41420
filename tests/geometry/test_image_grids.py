"""The one home of image grids (geometry.camera): pixel centres and cell centres in the README's
conventions (pixel (i, j) centre at (j, i); (u, v) = ((x + 0.5) / W, (y + 0.5) / H))."""

from __future__ import annotations

import numpy as np

from d4rt.geometry.camera import cell_centres_uv, pixel_grid, pixel_to_uv, uv_to_pixel


def test_pixel_grid_is_row_major_pixel_centres_and_strides():
    xy = pixel_grid(3, 4)
    assert xy.shape == (12, 2) and xy.dtype == np.float64
    assert xy[:5].tolist() == [[0, 0], [1, 0], [2, 0], [3, 0], [0, 1]]
    uv = pixel_to_uv(xy, 3, 4)
    assert np.allclose(uv[0], [0.125, 1 / 6]) and np.allclose(uv[-1], [0.875, 5 / 6])
    strided = pixel_grid(5, 7, stride=3)
    assert strided.tolist() == [[x, y] for y in (0, 3) for x in (0, 3, 6)]


def test_cell_centres_cover_the_image_evenly_whatever_its_size():
    uv = cell_centres_uv(4)
    assert uv.shape == (16, 2)
    assert np.allclose(uv[:4], [[0.125, 0.125], [0.375, 0.125], [0.625, 0.125], [0.875, 0.125]])
    assert np.allclose(uv.mean(0), 0.5) and len(cell_centres_uv(0)) == 0
    # On an image with as many pixels as cells, the cells are the pixels.
    assert np.allclose(uv_to_pixel(uv, 4, 4), pixel_grid(4, 4))
