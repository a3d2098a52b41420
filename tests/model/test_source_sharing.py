"""Queries that differ only in time share the source part of their embedding, with unchanged answers."""

import numpy as np
import torch

from d4rt.speed.decoder import random_sources, track_queries
from d4rt.geometry.umeyama import umeyama
from d4rt.model.encoded_scene import OUTPUT_KEYS
from d4rt.reconstruction.cameras import relative_poses

ATOL = 1e-5


def counting_source_rows(model):
    """Counts the (u, v, t_src) rows QueryEmbedding.source_tokens embeds."""
    rows = []
    original = model.query_embedding.source_tokens

    def counted(queries, patch_video, patch_sizes=None):
        rows.append(queries.shape[0] * queries.shape[1])
        return original(queries, patch_video, patch_sizes)

    model.query_embedding.source_tokens = counted
    return rows


def test_track_queries_share_their_source_embedding_and_answer_the_same(make_model, random_video):
    model = make_model()
    rows = counting_source_rows(model)
    frames = 6
    scene = model.encode(random_video(frames, 40, 56))
    sources = random_sources(9, frames, torch.Generator().manual_seed(3))
    queries = track_queries(sources, frames)  # 54 queries, 9 runs of 6
    # Chunks of 20 cut runs in two: a run is shared within its chunk.
    shared = scene.query(queries, chunk_size=20, share_sources=True)
    assert sum(rows) < len(queries) and sum(rows) <= 9 + 3
    rows.clear()
    unshared = scene.query(queries, chunk_size=20, share_sources=False)
    assert sum(rows) == len(queries)  # float32: no padding of the last chunk (padded_rows, under autocast only)
    for key in OUTPUT_KEYS:
        torch.testing.assert_close(shared[key], unshared[key], atol=ATOL, rtol=0)


def test_sharing_is_the_default_on_a_cpu(make_model, random_video):
    # On a CPU sharing is faster (1.07x); on a GPU it is not the default (0.76x on an H200: README).
    model = make_model()
    rows = counting_source_rows(model)
    frames = 4
    scene = model.encode(random_video(frames, 32, 32))
    queries = track_queries(random_sources(5, frames, torch.Generator().manual_seed(1)), frames)
    scene.query(queries, chunk_size=len(queries))
    assert sum(rows) == 5


def test_sharing_only_joins_consecutive_equal_sources(make_model, random_video, random_queries):
    model = make_model()
    scene = model.encode(random_video(4, 32, 32))
    queries = random_queries(30, 4)
    queries[5:9, :3] = queries[5, :3]       # a run of 4
    queries[12, :3] = queries[10, :3]       # equal but not consecutive: not joined, still right
    queries[20:22, :2] = queries[20, :2]    # same (u, v), different t_src: never joined
    queries[20, 2], queries[21, 2] = 0.0, 3.0
    rows = counting_source_rows(model)
    shared = scene.query(queries, share_sources=True)
    assert rows == [30 - 3]
    unshared = scene.query(queries, share_sources=False)
    for key in OUTPUT_KEYS:
        torch.testing.assert_close(shared[key], unshared[key], atol=ATOL, rtol=0)


def test_sharing_in_a_batched_forward_stays_within_each_clip(make_model):
    model = make_model()
    torch.manual_seed(1)
    video = torch.rand(2, 4, 64, 64, 3)
    # The last query of clip 0 and the first of clip 1 are equal: they must not be joined (other frames).
    base = track_queries(torch.tensor([[0.3, 0.6, 1.0], [0.7, 0.2, 3.0]]), 4)
    queries = torch.stack([base, base.flip(0)])
    queries[1, 0] = queries[0, -1]
    tokens = model.encode_tokens(video, torch.tensor([1.0, 2.0]))
    kv = model.decoder.project_scene(tokens)
    with torch.no_grad():
        shared = model.query_embedding(queries, video, share_sources=True)
        unshared = model.query_embedding(queries, video, share_sources=False)
        torch.testing.assert_close(shared, unshared, atol=ATOL, rtol=0)
        out_shared = model.decoder(shared, kv)
        out_unshared = model.decoder(unshared, kv)
    for key in OUTPUT_KEYS:
        torch.testing.assert_close(out_shared[key], out_unshared[key], atol=ATOL, rtol=0)


def test_batched_relative_poses_equal_the_per_frame_fits():
    rng = np.random.default_rng(0)
    here = rng.normal(size=(5, 40, 3))
    angle = 0.3
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    there = here @ rot.T + [0.1, -0.2, 0.5] + rng.normal(0, 0.01, here.shape)
    weights = rng.uniform(0.2, 1.0, (5, 40))
    here[1, 3] = np.nan        # non-finite points and non-positive weights are left out, per frame
    weights[2, :5] = 0.0
    weights[3, 7] = np.inf
    batched = relative_poses(here, there, weights)
    for f in range(5):
        w = np.where(np.isfinite(weights[f]) & (weights[f] > 0), weights[f], 0.0)
        single = umeyama(*(torch.from_numpy(a) for a in (here[f], there[f], w))).matrix().numpy()
        np.testing.assert_allclose(batched[f], single, atol=1e-12)
