"""The batched training entry point: gradients, bf16 autocast, activation checkpointing, consistency
with encode / query."""

import pytest
import torch

from d4rt.model.encoded_scene import OUTPUT_KEYS


def full_coverage_batch(config, batch=2, queries=64):
    """A batch that uses every frame index as t_src, t_tgt and t_cam, and the full input size, so every
    embedding row and position-table entry takes part."""
    frames = config.max_frames
    video = torch.rand(batch, frames, config.image_size, config.image_size, 3)
    t = torch.arange(queries) % frames
    times = torch.stack([t, t.roll(1), t.roll(2)], dim=-1).float()
    q = torch.cat([torch.rand(queries, 2), times], dim=-1)
    return video, q.expand(batch, -1, -1).clone(), torch.tensor([1.5, 0.6][:batch])


def total_loss(out):
    """Touches every output (the real losses live in the training package)."""
    return (out["points"].abs().mean() + out["uv"].square().mean() + out["visibility_logit"].mean()
            + out["motion"].abs().mean() + out["normals"][..., 0].mean() + out["confidence"].log().mean())


def test_gradients_reach_every_parameter(make_model):
    model = make_model(max_frames=6).train()
    video, queries, aspect = full_coverage_batch(model.config)
    out = model(video, queries, aspect)
    total_loss(out).backward()
    no_grad = [n for n, p in model.named_parameters() if p.grad is None]
    zero_grad = [n for n, p in model.named_parameters() if p.grad is not None and not p.grad.abs().sum() > 0]
    assert not no_grad, f"no gradient: {no_grad}"
    assert not zero_grad, f"zero gradient: {zero_grad}"
    assert all(torch.isfinite(p.grad).all() for p in model.parameters())
    # Every row of the time embeddings and of the temporal position table got a gradient.
    for table in (model.query_embedding.time_src.weight, model.encoder.pos_embed.time):
        assert (table.grad.abs().sum(-1) > 0).all()


def test_output_shapes_of_the_batched_forward(make_model):
    model = make_model()
    video, queries, aspect = torch.rand(3, 5, 64, 64, 3), torch.zeros(3, 7, 5), torch.ones(3)
    out = model(video, queries, aspect)
    shapes = {"points": (3, 7, 3), "uv": (3, 7, 2), "visibility": (3, 7), "visibility_logit": (3, 7),
              "motion": (3, 7, 3), "normals": (3, 7, 3), "confidence": (3, 7)}
    assert {k: tuple(v.shape) for k, v in out.items()} == shapes
    torch.testing.assert_close(out["visibility"], torch.sigmoid(out["visibility_logit"]))


def test_lower_resolution_training_input_runs(make_model):
    model = make_model()
    out = model(torch.rand(1, 2, 32, 48, 3), torch.rand(1, 4, 5) * torch.tensor([1, 1, 0, 0, 0]), torch.ones(1))
    assert out["points"].shape == (1, 4, 3)


def test_bf16_autocast_forward_and_backward(make_model):
    model = make_model(max_frames=4).train()
    video, queries, aspect = full_coverage_batch(model.config, queries=16)
    with torch.no_grad():
        reference = model(video, queries, aspect)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = model(video, queries, aspect)
        loss = total_loss(out)
    loss.backward()
    for key in reference:
        assert torch.isfinite(out[key]).all(), key
        # bf16 has ~3 significant digits; the answers must still be the same function.
        torch.testing.assert_close(out[key].float(), reference[key], atol=0.1, rtol=0.1)
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in model.parameters())


def test_bf16_autocast_encode_and_query(tiny_model, random_video, random_queries):
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = tiny_model.encode(random_video(3, 20, 20)).query(random_queries(5, 3))
    assert all(torch.isfinite(out[key].float()).all() for key in OUTPUT_KEYS)


def counted(forward, calls):
    def wrapper(*args):
        calls.append(1)
        return forward(*args)
    return wrapper


def test_activation_checkpointing_gives_the_same_values_and_gradients(make_model):
    video, queries, aspect = full_coverage_batch(make_model(max_frames=4).config, queries=16)
    grads, block_calls = [], []
    for checkpointing in (False, True):
        model = make_model(max_frames=4, gradient_checkpointing=checkpointing).train()
        calls = []
        for block in (*model.encoder.blocks, *model.decoder.blocks):
            block.forward = counted(block.forward, calls)  # (forward hooks do not fire when recomputing)
        out = model(video, queries, aspect)
        total_loss(out).backward()
        grads.append({n: p.grad for n, p in model.named_parameters()})
        block_calls.append(len(calls))
        if checkpointing:
            torch.testing.assert_close(out["points"], reference["points"], atol=1e-6, rtol=0)
        reference = out
    # Checkpointing really recomputes: every block runs again in the backward pass.
    assert block_calls[1] == 2 * block_calls[0]
    for name, grad in grads[0].items():
        torch.testing.assert_close(grads[1][name], grad, atol=1e-6, rtol=1e-5, msg=lambda m: f"{name}: {m}")


def test_batched_forward_matches_encode_then_query(tiny_model, random_video, random_queries):
    video = random_video(5, 40, 100)
    scene = tiny_model.encode(video)
    queries = random_queries(12, 5)
    with torch.no_grad():
        batched = tiny_model(scene.patch_video, queries[None], torch.tensor([100 / 40]))
    single = scene.query(queries)
    for key in OUTPUT_KEYS:
        torch.testing.assert_close(batched[key][0], single[key], atol=1e-5, rtol=0)


@pytest.mark.parametrize("activation", ["softplus", "one_plus_exp"])
def test_confidence_is_positive_under_both_activations(make_model, activation):
    model = make_model(confidence_activation=activation)
    with torch.no_grad():
        model.decoder.heads.heads["confidence"].bias.fill_(-30.0)
        out = model(torch.rand(1, 2, 64, 64, 3), torch.zeros(1, 3, 5), torch.ones(1))
    assert (out["confidence"] > 0).all()
    if activation == "one_plus_exp":
        assert (out["confidence"] >= 1).all()


def test_heads_run_in_float32_under_autocast(make_model):
    # The same decoder features give bit-identical float32 answers with and without bf16 autocast.
    heads = make_model().decoder.heads
    features = torch.randn(2, 5, heads.norm.normalized_shape[0]).bfloat16()
    reference = heads(features)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = heads(features)
    for key, value in out.items():
        assert value.dtype == torch.float32, key
        torch.testing.assert_close(value, reference[key], atol=0, rtol=0)


def test_bf16_autocast_answers_are_float32(tiny_model, random_video, random_queries):
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = tiny_model.encode(random_video(3, 20, 20)).query(random_queries(5, 3))
        batched = tiny_model(torch.rand(1, 2, 64, 64, 3), torch.zeros(1, 3, 5), torch.ones(1))
    assert {value.dtype for value in [*out.values(), *batched.values()]} == {torch.float32}


def test_a_model_cast_to_bf16_encodes_and_answers(make_model, random_video, random_queries):
    # model.to(torch.bfloat16) (pure bf16 inference on GPU): the float32 pixels and Fourier features follow
    # the weights' dtype, the answers stay float32 and are the same function as the float32 model's.
    model = make_model()
    video, queries = random_video(3, 20, 28), random_queries(7, 3)
    reference = model.encode(video).query(queries)
    out = model.to(torch.bfloat16).encode(video).query(queries)
    for key in OUTPUT_KEYS:
        assert out[key].dtype == torch.float32, key
        torch.testing.assert_close(out[key], reference[key], atol=0.1, rtol=0.1)
