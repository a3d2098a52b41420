import os

import numpy as np
import pytest
import torch

from d4rt.synthetic import render_clip

if os.environ.get("PYTEST_XDIST_WORKER"):
    # One torch thread per xdist worker (and per CLI subprocess a test starts, through the
    # environment): more threads than cores makes OpenMP spin and crawl.
    torch.set_num_threads(1)
    os.environ["OMP_NUM_THREADS"] = "1"


def pytest_collection_modifyitems(config, items):
    """Longest tests first, by their ``@pytest.mark.slow(seconds=...)`` (measured alone on a 2-core AMD EPYC):
    with xdist's work stealing (``--dist worksteal`` in pyproject.toml) an idle worker takes the tail of the
    other's queue, so the two workers end on short tests together instead of one waiting on a long one."""
    def seconds(item) -> float:
        mark = item.get_closest_marker("slow")
        return mark.kwargs.get("seconds", 30) if mark else 0

    items.sort(key=seconds, reverse=True)  # stable: the rest keep their collection order


@pytest.fixture(scope="session")
def room_clip():
    """A room with several moving objects, a moving camera and an articulated arm."""
    return render_clip(3, 8, 48, 64, environment="room", num_objects=6, camera_motion="orbit", articulated=True,
                       moving_fraction=0.8)


@pytest.fixture(scope="session")
def outdoor_clip():
    """Outdoors, hand-held camera with shake and a zoom, non-square frames."""
    return render_clip(11, 8, 40, 72, environment="outdoor", num_objects=5, camera_motion="handheld", shake=True,
                       zoom=True, moving_fraction=0.8)


@pytest.fixture(scope="session", params=["room", "outdoor"])
def clip(request, room_clip, outdoor_clip):
    return room_clip if request.param == "room" else outdoor_clip


def pixel_centre_queries(clip, frames, t_tgt=None, t_cam=None, dtype=np.float64):
    """Queries at every pixel centre of the given source frames (t_tgt = t_cam = t_src by default)."""
    h, w = clip.height, clip.width
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    out = []
    for f in frames:
        u = (xs.ravel() + 0.5) / w
        v = (ys.ravel() + 0.5) / h
        src = np.full(u.shape, f)
        out.append(np.stack([u, v, src, src if t_tgt is None else np.full(u.shape, t_tgt),
                             src if t_cam is None else np.full(u.shape, t_cam)], 1))
    return np.concatenate(out).astype(dtype)


def random_queries(rng, clip, n, dtype=np.float64):
    t = clip.num_frames
    return np.stack([rng.uniform(0, 1, n), rng.uniform(0, 1, n), rng.integers(0, t, n), rng.integers(0, t, n),
                     rng.integers(0, t, n)], 1).astype(dtype)


@pytest.fixture(autouse=True)
def _deterministic_torch():
    torch.manual_seed(0)
