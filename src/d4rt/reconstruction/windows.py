"""Long videos as overlapping windows (paper App. B): planning the windows, aligning each window's world
to the global one by Sim(3), the camera and depth recipes of one window, and handing tracks from one window
to the next. Offline (:class:`d4rt.reconstruction.Reconstruction`) and streaming
(:mod:`d4rt.reconstruction.streaming`) reconstruction share these functions.

Each window has its own world (the camera of its first frame) and, for a model, its own scale; window w
is mapped into the global world (the camera of frame 0) by a Sim(3) fitted with Umeyama on the most
confident part of the points its overlap shares with window w - 1. Every frame is answered by the
first window that contains it (its *owner*).
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import contextmanager

import numpy as np
import torch

from d4rt.config import GRAPH_GAPS, check_pose_pairs
from d4rt.errors import DegenerateFit, UserError
from d4rt.geometry.transforms import similarity_times_pose
from d4rt.geometry.umeyama import Similarity, umeyama
from d4rt.reconstruction.cameras import pose_graph, relative_poses
from d4rt.reconstruction.query_patterns import grid_queries

Windows = list[tuple[int, int]]  # [start, stop) frame ranges, ordered, consecutive ones overlapping


def plan_windows(num_frames: int, window: int | None, overlap: int | None = None) -> Windows:
    """Overlapping [start, stop) windows of at most ``window`` frames covering the video; consecutive
    windows share at least ``overlap`` frames (default a quarter of the window, at least 1)."""
    if window is None or window >= num_frames:
        return [(0, num_frames)]
    overlap = window_overlap(window, overlap)
    starts = list(range(0, num_frames - window, window - overlap))
    starts.append(num_frames - window)  # the last window ends with the video (it may overlap more)
    return [(s, s + window) for s in starts]


def window_overlap(window: int, overlap: int | None) -> int:
    """The frames consecutive windows of ``window`` frames share: ``overlap``, checked, or by default a
    quarter of the window (at least 1)."""
    if window < 2:
        raise UserError(f"window must be at least 2 frames, got {window}")
    overlap = max(1, window // 4) if overlap is None else overlap
    if not 1 <= overlap < window:
        raise UserError(f"overlap must be between 1 and window - 1 = {window - 1}, got {overlap}")
    return overlap


def owners(windows: Windows, frames) -> np.ndarray:
    """The first window containing each frame: (N,) int64. Windows are ordered and overlap, so it is
    the first one that stops after the frame."""
    stops = np.array([b for _, b in windows])
    return np.searchsorted(stops, np.asarray(frames), side="right").astype(np.int64)


def owned(windows: Windows, w: int) -> range:
    """The frames window ``w`` owns: from where the previous window stops to where it stops."""
    start, stop = windows[w]
    return range(windows[w - 1][1] if w else start, stop)


def align_windows(windows: Windows, ask: Callable[[int, np.ndarray], dict], uv: np.ndarray,
                  align_fraction: float) -> list[Similarity]:
    """Sim(3) from each window's world (camera of its first frame) to the global world (camera 0).

    ask(w, queries (N, 5) with global frame indices) -> answers of window w (numpy ``points``,
    ``confidence``); uv: (P, 2) grid queried at every shared frame, seen from each window's first
    camera; the most confident ``align_fraction`` of the pairs enter the Umeyama fit.
    """
    sims = [identity_similarity()]
    for w in range(1, len(windows)):
        sims.append(align_pair(lambda q, w=w: ask(w - 1, q), lambda q, w=w: ask(w, q), windows[w - 1], windows[w],
                               sims[w - 1], uv, align_fraction, w))
    return sims


def identity_similarity() -> Similarity:
    return Similarity(torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64),
                      torch.ones((), dtype=torch.float64))


def align_pair(ask_previous: Callable[[np.ndarray], dict], ask_this: Callable[[np.ndarray], dict],
               previous: tuple[int, int], this: tuple[int, int], previous_to_world: Similarity, uv: np.ndarray,
               align_fraction: float, index: int = 1) -> Similarity:
    """Sim(3) from window ``this``'s world to the global world, through the frames it shares with
    ``previous`` (whose Sim(3) is ``previous_to_world``); ask_*(queries with global frame indices) ->
    that window's answers. ``index`` names the window in errors."""
    (a0, b0), (a1, _) = previous, this
    shared = np.arange(a1, b0)
    prev = ask_previous(grid_queries(uv, shared, shared, np.full_like(shared, a0)))
    here = ask_this(grid_queries(uv, shared, shared, np.full_like(shared, a1)))
    conf = prev["confidence"] * here["confidence"]
    ok = np.isfinite(conf) & (conf > 0) & np.isfinite(prev["points"]).all(1) & np.isfinite(here["points"]).all(1)
    keep = np.nonzero(ok)[0]
    if len(keep) < 3:
        raise DegenerateFit(f"windows {index - 1} and {index} share too few confident points to be aligned")
    # The most confident align_fraction of the shared points (ties broken by order).
    order = keep[np.argsort(-conf[keep], kind="stable")]
    keep = order[: max(3, int(np.ceil(align_fraction * len(order))))]
    target = previous_to_world.apply(torch.from_numpy(prev["points"][keep]))
    return umeyama(torch.from_numpy(here["points"][keep]), target, with_scale=True)


def window_camera_grid(ask: Callable[[np.ndarray], dict], first: int, frames: np.ndarray, uv: np.ndarray,
                       window_to_world: Similarity, pairs: str = "first") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The camera recipe's answers for the frames one window owns (paper Sec. 2.1): grid ``uv`` (P, 2) of
    frame i seen in camera i (for intrinsics) and in other cameras of the window (for the pose): its first
    camera ``first`` (pairs="first"), camera i - 1 with the fits chained from ``first`` (pairs="adjacent"), or
    cameras i - g for g in ``GRAPH_GAPS`` inside the window, every pose solved at once (pairs="graph",
    :func:`d4rt.reconstruction.cameras.pose_graph`).

    ask(queries with global frame indices) -> the window's answers; frames: (F,) owned frames, ascending.
    Returns points (F, P, 3) in camera i, their confidence (F, P), and cam_to_world (F, 4, 4) of each
    frame in the global world (the rigid fit between the two views, after the window's Sim(3)).
    """
    check_pose_pairs(pairs)
    n = len(uv)
    frames = np.asarray(frames, dtype=np.int64)
    if not len(frames):
        return np.zeros((0, n, 3)), np.zeros((0, n)), np.zeros((0, 4, 4))
    # A chain or a graph needs every frame from the window's first one, owned or not.
    asked = frames if pairs == "first" else np.arange(first, frames.max() + 1)
    if pairs == "first":
        others = [[first] for _ in asked]
    elif pairs == "adjacent":
        others = [[max(i - 1, first)] for i in asked]
    else:  # only the gaps that fit in the window: the first frame has none (it is the window's world)
        others = [[i - g for g in GRAPH_GAPS if i - g >= first] for i in asked]
    # One call, each point's queries side by side: they differ only in t_cam, so the model embeds their
    # shared (u, v, t_src) once (EncodedScene.query, share_sources).
    blocks = [np.stack([grid_queries(uv, [i], [i], [c]) for c in [i, *o]], 1).reshape(-1, 5)
              for i, o in zip(asked, others)]
    answers = ask(np.concatenate(blocks))
    bounds = np.cumsum([0] + [len(b) for b in blocks])
    per_frame = [{key: v[a:b].reshape(n, 1 + len(o), *v.shape[1:]) for key, v in answers.items()}
                 for a, b, o in zip(bounds[:-1], bounds[1:], others)]
    here = {key: np.stack([f[key][:, 0] for f in per_frame]) for key in answers}
    edges = [(i, j) for i, o in enumerate(others) for j in o]  # (index into asked, global frame of the other camera)
    if edges:  # none only for a graph over the window's first frame alone, which is its world
        there = {key: np.stack([f[key][:, c] for f, o in zip(per_frame, others) for c in range(1, 1 + len(o))])
                 for key in ("points", "confidence")}
        source = np.array([i for i, _ in edges], dtype=np.int64)
        # Every fit at once (one batched SVD, no loop over frames).
        weights = _finite_weights(here["confidence"][source] * there["confidence"])
        fits = relative_poses(here["points"][source], there["points"], weights)
    else:
        fits = np.zeros((0, 4, 4))
    if pairs == "first":
        poses = fits
    elif pairs == "adjacent":
        poses = fits
        poses[0] = np.eye(4)  # the window's first camera is its world
        for i in range(1, len(poses)):
            poses[i] = poses[i - 1] @ poses[i]  # camera i -> camera i - 1 -> ... -> the first camera
    else:
        pairs_local = np.array([(i, j - first) for i, j in edges], dtype=np.int64).reshape(-1, 2)
        poses = pose_graph(len(asked), pairs_local, fits)
    pick = np.searchsorted(asked, frames)
    sim = window_to_world.matrix().double().numpy()
    c2w = np.stack([similarity_times_pose(sim, pose) for pose in poses[pick]])
    return here["points"][pick], here["confidence"][pick], c2w


def window_depth(ask: Callable[[np.ndarray], dict], frames: np.ndarray, uv: np.ndarray, scale: float, height: int,
                 width: int) -> tuple[np.ndarray, np.ndarray]:
    """Depth maps of the frames one window owns: every pixel of ``uv`` (height * width, 2) with
    t_src = t_tgt = t_cam; z times the window's Sim(3) scale. Returns depth, confidence (F, H, W) float32."""
    out = ask(grid_queries(uv, frames, frames, frames))
    depth = (out["points"][:, 2] * scale).reshape(-1, height, width).astype(np.float32)
    return depth, out["confidence"].reshape(-1, height, width).astype(np.float32)


def _finite_weights(w: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(w) & (w > 0), w, 0.0)


def hand_off(windows: Windows, answers: dict, win: int, nxt: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where tracks decoded in window ``win`` (answers ``uv`` (N, K, 2), ``visibility`` (N, K) over its
    K frames) continue in window ``nxt``: for each, the frame shared by both where it is most visible
    and its (u, v) there. Returns (ok (N,), uv (N, 2), global frame (N,)); ok is False where there is no
    such window or the track is hidden (or outside the image) in every shared frame: it cannot be
    carried."""
    count = len(answers["uv"])
    if not 0 <= nxt < len(windows):
        return np.zeros(count, dtype=bool), np.zeros((count, 2)), np.zeros(count, dtype=np.int64)
    (a, b), (na, nb) = windows[win], windows[nxt]
    shared = np.arange(max(a, na), min(b, nb)) - a
    vis = np.nan_to_num(answers["visibility"][:, shared], nan=0.0)  # NaN must not win argmax
    best = np.argmax(vis, axis=1)
    rows = np.arange(count)
    k = shared[best]
    uv = answers["uv"][rows, k]
    ok = (vis[rows, best] > 0.5) & np.all((uv >= 0) & (uv <= 1), 1)
    return ok, uv, k + a


@contextmanager
def keeping_windows(source, count: int):
    """Let a source that caches encoded windows keep ``count`` of them for the duration."""
    keeping = getattr(source, "keeping", None)
    if keeping is None:
        yield
    else:
        with keeping(count):
            yield
