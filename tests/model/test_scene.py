"""encode / query: the encoder runs once, keys and values are cached, any video shape works."""

import numpy as np
import pytest
import torch

from d4rt.model.encoded_scene import OUTPUT_KEYS


class CallCounter:
    """Counts forward calls of a module."""

    def __init__(self, module):
        self.calls = 0
        module.register_forward_hook(self._hook)

    def _hook(self, *_):
        self.calls += 1


class MethodCounter:
    """Counts calls of one bound method (here: a decoder block's key/value projection)."""

    def __init__(self, obj, name):
        self.calls = 0
        original = getattr(obj, name)

        def counted(*args, **kwargs):
            self.calls += 1
            return original(*args, **kwargs)

        setattr(obj, name, counted)


def test_encoder_runs_once_however_many_chunks_are_decoded(make_model, random_video, random_queries):
    model = make_model()
    encoder_calls = CallCounter(model.encoder)
    decoder_calls = CallCounter(model.decoder)
    scene = model.encode(random_video(5, 30, 40))
    scene.query(random_queries(100, 5), chunk_size=7)  # 15 chunks
    scene.query(random_queries(10, 5), chunk_size=3)   # 4 more
    assert encoder_calls.calls == 1
    assert decoder_calls.calls == 15 + 4


def test_preallocated_answers_equal_the_chunks_bit_for_bit(make_model, random_video, random_queries):
    """query() writes each chunk's answers into tensors of the final size: the same bits as decoding the
    chunks one by one and concatenating them (the uneven last chunk included), under bf16 autocast too,
    where the last chunk (3 queries) is decoded padded to 4 (padded_rows) and its 4th answer dropped."""
    model = make_model()
    scene = model.encode(random_video(5, 30, 40))
    queries = random_queries(23, 5)
    for autocast in (False, True):
        with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
            answers = scene.query(queries, chunk_size=5)
            chunks = [queries[i:i + 5].float() for i in range(0, 23, 5)]
            if autocast:
                chunks[-1] = torch.cat([chunks[-1], chunks[-1][-1:]])
            pieces = [{k: v[0, :min(5, 23 - 5 * i)] for k, v in
                       model.decode(c[None], scene.scene_kv(True), scene.patch_video, True).items()}
                      for i, c in enumerate(chunks)]
        for key in OUTPUT_KEYS:
            expected = torch.cat([piece[key] for piece in pieces])
            assert answers[key].dtype == expected.dtype and torch.equal(answers[key], expected), (key, autocast)


def test_scene_keys_values_are_projected_once_per_layer_when_cached(make_model, random_video, random_queries):
    model = make_model()
    projections = [MethodCounter(block.attn, "project_context") for block in model.decoder.blocks]
    scene = model.encode(random_video(4, 32, 32))
    queries = random_queries(40, 4)
    cached = scene.query(queries, chunk_size=8, cache_kv=True)
    scene.query(queries, chunk_size=8, cache_kv=True)  # a second call reuses the cache too
    assert [p.calls for p in projections] == [1] * len(projections)

    uncached = scene.query(queries, chunk_size=8, cache_kv=False)
    assert [p.calls for p in projections] == [1 + 5] * len(projections)
    for key in OUTPUT_KEYS:
        torch.testing.assert_close(cached[key], uncached[key], atol=1e-5, rtol=0)


def test_config_switch_disables_the_cache(make_model, random_video, random_queries):
    model = make_model(cache_scene_kv=False)
    projections = MethodCounter(model.decoder.blocks[0].attn, "project_context")
    scene = model.encode(random_video(2, 16, 16))
    scene.query(random_queries(10, 2), chunk_size=5)
    assert projections.calls == 2


@pytest.mark.parametrize("frames", [1, 2, 3, 5, 8, 24])
def test_any_number_of_frames_up_to_the_maximum(tiny_model, random_video, random_queries, frames):
    scene = tiny_model.encode(random_video(frames, 24, 40))
    assert scene.num_frames == frames
    out = scene.query(random_queries(6, frames))
    assert out["points"].shape == (6, 3)
    # The last real frame is queryable as source, target and camera.
    last = torch.tensor([[0.5, 0.5, frames - 1, frames - 1, frames - 1]], dtype=torch.float32)
    assert torch.isfinite(scene.query(last)["points"]).all()


def test_odd_clip_keeps_its_last_frame(tiny_model, random_video):
    video = random_video(5, 32, 32)
    edited = video.clone()
    edited[4] = 255 - edited[4]  # only the unpaired last frame changes
    a, b = tiny_model.encode(video), tiny_model.encode(edited)
    # Its tubelet (time step 2) is padded with a copy of it, so the encoder sees the change.
    grid = tiny_model.config.grid_size ** 2
    assert not torch.allclose(a.tokens[0, 2 * grid:3 * grid], b.tokens[0, 2 * grid:3 * grid])
    query = torch.tensor([[0.3, 0.6, 4.0, 4.0, 4.0]])
    assert not torch.allclose(a.query(query)["points"], b.query(query)["points"])


@pytest.mark.parametrize("height, width", [(64, 64), (17, 203), (240, 32), (1, 1), (720, 1280)])
def test_any_frame_size_and_aspect_ratio(tiny_model, random_video, random_queries, height, width):
    scene = tiny_model.encode(random_video(3, height, width))
    assert (scene.height, scene.width) == (height, width)
    assert scene.aspect_ratio == pytest.approx(width / height)
    assert scene.tokens.shape == (1, tiny_model.config.num_scene_tokens(3), tiny_model.config.encoder_dim)
    out = scene.query(random_queries(4, 3))
    assert all(torch.isfinite(out[key]).all() for key in OUTPUT_KEYS)


def test_aspect_ratio_token_takes_part_in_global_attention(make_model):
    video = torch.rand(1, 2, 64, 64, 3)
    with torch.no_grad():
        model = make_model()
        wide, tall = (model.encode_tokens(video, torch.tensor([r])) for r in (2.0, 0.5))
        # The same pixels told they came from frames of different shapes give different video tokens.
        assert not torch.allclose(wide[:, :-1], tall[:, :-1], atol=1e-4)
        # Were every block frame-local (a config refuses that), nothing would carry it to the video tokens.
        model.encoder.is_global = lambda index: False
        wide, tall = (model.encode_tokens(video, torch.tensor([r])) for r in (2.0, 0.5))
        torch.testing.assert_close(wide[:, :-1], tall[:, :-1], atol=0, rtol=0)


def test_output_shapes_types_and_ranges(tiny_model, random_video, random_queries):
    scene = tiny_model.encode(random_video(4, 36, 48))
    out = scene.query(random_queries(11, 4))
    shapes = {"points": (11, 3), "uv": (11, 2), "visibility": (11,), "motion": (11, 3),
              "normals": (11, 3), "confidence": (11,)}
    assert {k: tuple(v.shape) for k, v in out.items()} == shapes
    assert ((out["visibility"] > 0) & (out["visibility"] < 1)).all()
    assert (out["confidence"] > 0).all()
    torch.testing.assert_close(out["normals"].norm(dim=-1), torch.ones(11), atol=1e-5, rtol=0)
    assert not out["points"].requires_grad
    empty = scene.query(torch.zeros(0, 5))
    assert {k: tuple(v.shape) for k, v in empty.items()} == {k: (0,) + s[1:] for k, s in shapes.items()}


def test_uint8_float_and_numpy_videos_agree(tiny_model, random_video, random_queries):
    video = random_video(3, 20, 30)
    queries = random_queries(5, 3)
    a = tiny_model.encode(video).query(queries)
    b = tiny_model.encode(video.float() / 255).query(queries)
    c = tiny_model.encode(video.numpy()).query(queries.numpy())
    for key in OUTPUT_KEYS:
        torch.testing.assert_close(a[key], b[key], atol=1e-5, rtol=0)
        torch.testing.assert_close(a[key], c[key], atol=0, rtol=0)


def test_original_resolution_patches_come_from_the_original_frames(make_model, random_video, random_queries):
    model = make_model(rgb_patch_source="original")
    video = random_video(3, 150, 90)
    scene = model.encode(video)
    assert scene.patch_video.shape == (1, 3, 150, 90, 3) and scene.patch_video.dtype == torch.uint8
    queries = random_queries(6, 3)
    # The batched entry point, given the same encoder input and the original frames, answers the same.
    resized = torch.nn.functional.interpolate(video.permute(0, 3, 1, 2).float() / 255, size=(64, 64),
                                              mode="bilinear", antialias=True).permute(0, 2, 3, 1)
    with torch.no_grad():
        batched = model(resized[None], queries[None], torch.tensor([90 / 150]), patch_video=video[None])
    for key in OUTPUT_KEYS:
        torch.testing.assert_close(scene.query(queries)[key], batched[key][0], atol=1e-5, rtol=0)


def test_no_patch_configuration_runs(make_model, random_video, random_queries):
    model = make_model(rgb_patch_size=0)
    assert model.query_embedding.patch_proj is None
    scene = model.encode(random_video(2, 16, 16))
    assert scene.patch_video is None
    assert scene.query(random_queries(3, 2))["points"].shape == (3, 3)


def test_numpy_queries_of_float64_are_accepted(tiny_model, random_video):
    scene = tiny_model.encode(random_video(2, 8, 8))
    out = scene.query(np.array([[0.25, 0.75, 1, 0, 1]], dtype=np.float64))
    assert out["uv"].shape == (1, 2)


def test_encoder_input_is_the_antialiased_bilinear_resize(tiny_model, random_video):
    video = random_video(10, 90, 160)  # more frames than one resize step, to cover the stitching
    scene = tiny_model.encode(video)
    expected = torch.nn.functional.interpolate(video.permute(0, 3, 1, 2).float() / 255, size=(64, 64),
                                               mode="bilinear", antialias=True).permute(0, 2, 3, 1)
    torch.testing.assert_close(scene.patch_video[0], expected, atol=1e-6, rtol=0)


def test_cached_keys_follow_the_autocast_dtype(make_model, random_video, random_queries):
    # Keys cached under bf16 autocast must not be reused by a float32 query (dtype error or rounded keys),
    # and float32 keys must not be reused under autocast either: each setting answers as if uncached.
    model = make_model()
    scene = model.encode(random_video(4, 24, 32))
    queries = random_queries(9, 4)
    float32 = scene.query(queries, cache_kv=False)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        bf16 = scene.query(queries, cache_kv=False)
    for first in ("bf16", "float32"):
        scene.clear_cache()
        for setting in (first, "float32" if first == "bf16" else "bf16", first):
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=setting == "bf16"):
                out = scene.query(queries)
            expected = bf16 if setting == "bf16" else float32
            for key in OUTPUT_KEYS:
                torch.testing.assert_close(out[key], expected[key], atol=0, rtol=0)


def test_original_frames_are_stored_contiguous(make_model, random_video, random_queries):
    # A clip handed over as a view (here channels-first permuted back) is made contiguous once in encode,
    # not flattened into a fresh copy for every chunk of queries; the answers are unchanged.
    model = make_model(rgb_patch_source="original")
    video = random_video(3, 30, 50)
    view = video.permute(0, 3, 1, 2).contiguous().permute(0, 2, 3, 1)
    assert not view.is_contiguous()
    scene = model.encode(view)
    assert scene.patch_video.is_contiguous()
    queries = random_queries(8, 3)
    expected = model.encode(video).query(queries)
    for key, value in scene.query(queries, chunk_size=3).items():
        # Not bit-identical: the resize kernel differs with the memory layout.
        torch.testing.assert_close(value, expected[key], atol=1e-5, rtol=0)


def test_cached_and_recomputed_keys_values_answer_the_same_at_benchmark_chunks(make_model, random_video,
                                                                             random_queries):
    """As ``d4rt bench`` compares them: chunks of 256, random and track queries, float32, to 1e-5."""
    from d4rt.speed.decoder import random_sources, track_queries

    model = make_model()
    scene = model.encode(random_video(8, 48, 48))
    tracks = track_queries(random_sources(40, 8, torch.Generator().manual_seed(5)), 8)
    queries = torch.cat([random_queries(300, 8), tracks])  # 620 queries: 3 chunks of 256
    projections = [MethodCounter(block.attn, "project_context") for block in model.decoder.blocks]
    cached = scene.query(queries, chunk_size=256, cache_kv=True)
    assert [p.calls for p in projections] == [1] * len(projections)
    uncached = scene.query(queries, chunk_size=256, cache_kv=False)
    assert [p.calls for p in projections] == [1 + 3] * len(projections)
    for key in OUTPUT_KEYS:
        assert cached[key].dtype == torch.float32
        torch.testing.assert_close(cached[key], uncached[key], atol=1e-5, rtol=0)


def test_recipes_never_recompute_the_scene_keys_values(make_model, random_video):
    """Depth, cameras and tracks of one window: each decoder layer projects the scene once in all."""
    model = make_model()
    video = random_video(6, 24, 32)
    encoder_calls = CallCounter(model.encoder)
    projections = [MethodCounter(block.attn, "project_context") for block in model.decoder.blocks]
    rec = model.reconstruct(video, chunk_size=100, grid=6)  # many small chunks
    rec.depth()
    rec.cameras()
    rec.tracks(np.array([[0, 3.0, 4.0], [5, 10.0, 20.0]]))
    assert encoder_calls.calls == 1
    assert [p.calls for p in projections] == [1] * len(projections)


def test_under_autocast_a_short_chunk_is_decoded_as_a_power_of_two(make_model, random_video, random_queries):
    """padded_rows: oneDNN keeps a kernel per matrix shape, so the last chunk is decoded padded to the next
    power of two (repeats of its last query, dropped); its answers stay those of the unpadded decode."""
    model = make_model()
    scene = model.encode(random_video(5, 30, 40))
    queries = random_queries(37, 5)
    seen = []
    decode = model.decode
    model.decode = lambda q, *a, **k: seen.append(q.shape[1]) or decode(q, *a, **k)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        answers = scene.query(queries, chunk_size=16)
        model.decode = decode
        unpadded = decode(queries[None, 32:].float(), scene.scene_kv(True), scene.patch_video, True)
    assert seen == [16, 16, 8] and answers["points"].shape == (37, 3)
    for key in OUTPUT_KEYS:
        torch.testing.assert_close(answers[key][32:], unpadded[key][0], atol=2e-2, rtol=2e-2)
