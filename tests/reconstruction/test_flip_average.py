"""Test-time flip averaging (``d4rt.reconstruction.flip_average``): the mirror conventions agree with pinhole
geometry on the exact oracle, a flip-averaged model is exactly mirror-equivariant, and the option follows the
model's config through every path that encodes (offline, streaming, the evaluation's predictor, the CLI)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.evaluation.partial_results import checkpoint_fingerprint
from d4rt.model import D4RT
from d4rt.reconstruction import Reconstruction
from d4rt.reconstruction.flip_average import (FlipAveraged, flip_averaged, mirror_answers, mirror_queries,
                                              mirror_video)
from d4rt.reconstruction.sources import ModelSource, encoded_bytes
from d4rt.reconstruction.streaming import StreamingReconstruction


class Mirrored:
    """Answers about the mirror of the video ``answerer`` answers about, through the module's own mirror."""

    def __init__(self, answerer):
        self.answerer, self.num_frames = answerer, answerer.num_frames

    def query(self, queries, **options):
        return mirror_answers(self.answerer.query(mirror_queries(queries), **options))


def test_the_mirror_of_an_exact_scene_is_the_pinhole_mirror(clip):
    # The recipes read the mirrored oracle as a camera with the same focal length and the principal point
    # mirrored (cx -> W - 1 - cx: intrinsics put the top-left pixel's centre at x = 0, README), the same depth
    # maps mirrored and the camera path mirrored (x -> -x in every camera, so R -> S R S and t -> S t with
    # S = diag(-1, 1, 1)): u -> 1 - u and x -> -x are one mirror, as pinhole geometry says.
    plain = Reconstruction.from_clip(clip)
    mirrored = Reconstruction(Mirrored(clip.oracle), mirror_video(clip.rgb))
    k, k_mirrored = plain.cameras().intrinsics, mirrored.cameras().intrinsics
    np.testing.assert_allclose(k_mirrored[:, 0, 0], k[:, 0, 0], rtol=1e-6)
    np.testing.assert_allclose(k_mirrored[:, 0, 2], clip.width - 1 - k[:, 0, 2], atol=1e-5)
    np.testing.assert_allclose(k_mirrored[:, 1, 2], k[:, 1, 2], atol=1e-5)
    np.testing.assert_allclose(k, clip.intrinsics, rtol=1e-5, atol=1e-4)  # and the plain one is exact
    np.testing.assert_allclose(mirrored.depth().depth, plain.depth().depth[:, :, ::-1], rtol=1e-9, equal_nan=True)
    s = np.diag([-1.0, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(mirrored.cameras().cam_to_world, s @ plain.cameras().cam_to_world @ s, atol=1e-6)


def test_flip_averaging_an_exactly_mirror_symmetric_answerer_changes_nothing(clip):
    rng = np.random.default_rng(0)
    queries = np.stack([rng.uniform(0, 1, 500), rng.uniform(0, 1, 500), *rng.integers(0, clip.num_frames, (3, 500))], 1)
    both = FlipAveraged(clip.oracle, Mirrored(clip.oracle)).query(queries)
    alone = clip.oracle.query(queries)
    for key in both:  # the model's answers (the oracle adds its own "valid")
        np.testing.assert_allclose(both[key].numpy(), alone[key].numpy(), atol=1e-12, equal_nan=True, err_msg=key)


@pytest.fixture(scope="module")
def model():
    return D4RT.from_pretrained()


def test_a_flip_averaged_model_answers_a_mirrored_video_as_the_mirror_of_its_answers(model, room_clip):
    encode = flip_averaged(model.encode)
    video = room_clip.rgb
    rng = np.random.default_rng(1)
    queries = np.stack([rng.uniform(0, 1, 300), rng.uniform(0, 1, 300), *rng.integers(0, len(video), (3, 300))], 1)
    on_video = encode(video).query(queries)
    on_mirror = mirror_answers(encode(mirror_video(video)).query(mirror_queries(queries)))
    for key in on_video:
        torch.testing.assert_close(on_mirror[key], on_video[key], atol=1e-5, rtol=1e-5, msg=key)
    # ... while the model alone is not (else averaging would change nothing), and the average is of the two.
    plain = model.encode(video).query(queries)
    mirrored = mirror_answers(model.encode(mirror_video(video)).query(mirror_queries(queries)))
    assert (plain["points"] - mirrored["points"]).abs().max() > 1e-3
    torch.testing.assert_close(on_video["points"], (plain["points"] + mirrored["points"]) / 2, atol=1e-5, rtol=1e-5)
    assert torch.allclose(on_video["normals"].norm(dim=-1), torch.ones(300), atol=1e-5)


def test_the_option_follows_the_model_config_unless_told(model, room_clip):
    flipping = D4RT(model.config.replace(flip_average=True))
    flipping.load_state_dict(model.state_dict())
    video = room_clip.rgb[:4]
    assert isinstance(ModelSource(flipping, video).window(0, 4), FlipAveraged)
    assert not isinstance(ModelSource(model, video).window(0, 4), FlipAveraged)
    assert not isinstance(ModelSource(flipping, video, flip_average=False).window(0, 4), FlipAveraged)
    told = Reconstruction.from_model(model, video, flip_average=True, progress=False)
    own = Reconstruction.from_model(flipping, video, progress=False)
    np.testing.assert_array_equal(told.depth().depth, own.depth().depth)
    assert not np.array_equal(told.depth().depth, Reconstruction.from_model(model, video, progress=False).depth().depth)
    # The window cache counts both encodings.
    scene = flipped = ModelSource(flipping, video).window(0, 4)
    assert encoded_bytes(flipped) == 2 * encoded_bytes(scene.plain) > 0
    # Streaming reads the same default, so that its answers are the offline ones.
    stream = StreamingReconstruction.from_model(flipping, window=4, overlap=1, depth_size=(6, 8))
    results = [r for frame in video for r in stream.push(frame)] + stream.finish()
    np.testing.assert_array_equal(np.concatenate([r.depth for r in results]),
                                  Reconstruction.from_model(flipping, video, window=4, overlap=1,
                                                            progress=False).depth((6, 8)).depth)


def test_the_config_field_is_checked_and_saved(tmp_path, model):
    assert D4RTConfig.from_json(D4RTConfig.preset("tiny", flip_average=True).to_json()).flip_average is True
    assert D4RTConfig.preset("tiny").flip_average is False
    with pytest.raises(UserError, match="config field flip_average must be true or false"):
        D4RTConfig.preset("tiny", flip_average="yes")
    with pytest.raises(TypeError, match="flip_average must be true or false"):
        ModelSource(model, np.zeros((2, 8, 8, 3), np.uint8), flip_average=1)
    # A resumed evaluation never mixes rows answered with and without it; rows of the model's own choice keep
    # the fingerprint they had before the option existed.
    model.save_pretrained(tmp_path)
    fingerprints = {checkpoint_fingerprint(tmp_path, "adjacent", flip) for flip in (None, True, False)}
    assert len(fingerprints) == 3


def test_mirror_helpers_keep_their_inputs(room_clip):
    video = room_clip.rgb[:2]
    np.testing.assert_array_equal(mirror_video(mirror_video(video)), video)
    assert torch.equal(mirror_video(torch.from_numpy(video)), torch.from_numpy(mirror_video(video)))
    queries = torch.tensor([[0.25, 0.5, 0.0, 1.0, 1.0]])
    assert mirror_queries(queries)[0, 0] == 0.75 and queries[0, 0] == 0.25
    assert mirror_queries([[0.0, 0.5, 0, 0, 0]])[0, 0] == 1.0


def test_it_averages_every_answer_a_query_has():
    from d4rt.model.encoded_scene import OUTPUT_KEYS
    from d4rt.reconstruction.flip_average import ANSWER_KEYS

    assert ANSWER_KEYS == OUTPUT_KEYS
