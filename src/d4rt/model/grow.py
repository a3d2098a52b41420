"""Grow a trained model deeper without changing what it computes (function-preserving deepening).

Why (issue 14): the tiny model trained on this CPU stopped learning (48,000 clips lowered its held-out 3D loss
by under 2%, docs/training.md stage 41). Whether that is the model's capacity is answered by giving it more
blocks and training on; starting the larger model from scratch would throw away days of CPU training.

A pre-norm residual block ``x + f(norm(x))`` whose output projections (``attn.proj``, ``mlp.fc2``) are zero is
the identity, so new blocks with zeroed output projections and freshly initialised everything else leave the
model's outputs exactly as they were; their output projections still receive gradients, so they start learning
at the first step (the same start as ReZero or GPT-2's scaled residual initialisation, taken to zero).

Where the new blocks go: the encoder alternates frame-local and global blocks in groups of
``global_attention_every`` (the last block of a group is global), so it grows by whole groups and every old
group keeps its kind of attention; the old groups are spread evenly over the new depth (first and last kept in
place) with the new groups between them. Decoder blocks are all alike and are spread the same way.

A model can also be given a larger input (``with_input_size``): the encoder's spatial position table is resized to
the new tubelet grid exactly as the encoder resizes it at run time for another grid, and the query's Fourier
frequencies are pinned to the old ones (by default they follow the input's Nyquist frequency), so every weight keeps
its meaning; what changes is that the encoder sees more pixels, and the 9x9 RGB patch a smaller part of the image.

A model can also be given shorter tubelets (``with_tubelet_frames``, e.g. one frame per token instead of two): each
new token's patch-embedding kernel is the old kernel summed over the frames the new tubelet no longer spans, and time
step j's position row is that of the old step holding frame j's tubelet, so on a clip that does not move every old
token comes out once per new time step, exactly as before. Attention over duplicated keys and values weighs them as
it weighed the originals, except against the aspect-ratio token, whose share of a global block or of the decoder's
cross-attention halves with each halving of the tubelet: the one place the copy is not the old model's function.
Overlapping tubelets (``with_tubelet_stride``: a two-frame tubelet every frame) keep the kernel as it is, so a token
still sees the motion between its two frames; the tubelets that start where the old ones did are the old tokens
exactly, those between them new, and each takes the time position row of the old tubelet holding its first frame.
"""

from __future__ import annotations

import torch

from d4rt.errors import UserError
from d4rt.model.d4rt import D4RT


def spread(old: int, new: int) -> list[int]:
    """Positions in ``range(new)`` for ``old`` items, evenly spread, first and last at the ends; ``old <= new``."""
    if old == 1:
        return [0]
    return [round(k * (new - 1) / (old - 1)) for k in range(old)]


def _zero_outputs(block: torch.nn.Module) -> None:
    """Make a pre-norm residual block the identity: zero its attention and MLP output projections."""
    for layer in (block.attn.proj, block.mlp.fc2):
        torch.nn.init.zeros_(layer.weight)
        torch.nn.init.zeros_(layer.bias)


def _move_blocks(state: dict[str, torch.Tensor], prefix: str, mapping: dict[int, int]) -> dict[str, torch.Tensor]:
    """The tensors of ``state`` under ``prefix`` (``encoder.blocks.``), block index ``i`` renamed ``mapping[i]``."""
    moved = {}
    for key, value in state.items():
        if key.startswith(prefix):
            index, rest = key[len(prefix):].split(".", 1)
            moved[f"{prefix}{mapping[int(index)]}.{rest}"] = value
    return moved


def deepen(model: D4RT, encoder_depth: int | None = None, decoder_depth: int | None = None,
           seed: int = 0) -> D4RT:
    """A copy of ``model`` with ``encoder_depth`` / ``decoder_depth`` blocks (None keeps a depth) that computes
    the same outputs; the new blocks are seeded with ``seed`` and zeroed at their outputs.

    Raises :class:`UserError` if a depth shrinks or the encoder does not grow by whole local/global groups.
    """
    config = model.config
    encoder_depth = config.encoder_depth if encoder_depth is None else encoder_depth
    decoder_depth = config.decoder_depth if decoder_depth is None else decoder_depth
    group = config.global_attention_every
    if encoder_depth < config.encoder_depth or decoder_depth < config.decoder_depth:
        raise UserError(f"deepen grows a model: depths {config.encoder_depth}/{config.decoder_depth} cannot become "
                        f"{encoder_depth}/{decoder_depth}")
    if config.encoder_depth % group or encoder_depth % group:
        raise UserError(f"the encoder grows by whole groups of global_attention_every = {group} blocks: "
                        f"{config.encoder_depth} -> {encoder_depth} does not")
    grown_config = config.replace(encoder_depth=encoder_depth, decoder_depth=decoder_depth)
    torch.manual_seed(seed)
    grown = D4RT(grown_config)
    groups = spread(config.encoder_depth // group, encoder_depth // group)
    encoder_map = {g * group + j: new * group + j for g, new in enumerate(groups) for j in range(group)}
    decoder_map = dict(enumerate(spread(config.decoder_depth, decoder_depth)))
    for blocks, mapping in ((grown.encoder.blocks, encoder_map), (grown.decoder.blocks, decoder_map)):
        for index, block in enumerate(blocks):
            if index not in mapping.values():
                _zero_outputs(block)
    state = grown.state_dict()
    old = model.state_dict()
    state.update({k: v for k, v in old.items() if not k.startswith(("encoder.blocks.", "decoder.blocks."))})
    state.update(_move_blocks(old, "encoder.blocks.", encoder_map))
    state.update(_move_blocks(old, "decoder.blocks.", decoder_map))
    grown.load_state_dict(state, strict=True)
    return grown.train(model.training)


def with_input_size(model: D4RT, image_size: int) -> D4RT:
    """A copy of ``model`` whose encoder input is ``image_size`` pixels a side (see the module docstring).

    The spatial position table ``(grid, grid, dim)`` becomes the bilinear resize the encoder would compute for the
    new grid at run time; ``fourier_max_frequency`` is set to the model's current one. Raises :class:`UserError`
    if ``image_size`` is not a multiple of the patch size.
    """
    config = model.config
    resized_config = config.replace(image_size=image_size, fourier_max_frequency=config.fourier_max)
    resized = D4RT(resized_config)
    grid = resized_config.grid_size
    state = model.state_dict()
    with torch.no_grad():
        state["encoder.pos_embed.space"] = model.encoder.pos_embed.space_table(grid, grid).clone()
    resized.load_state_dict(state, strict=True)
    return resized.train(model.training)


def with_tubelet_frames(model: D4RT, tubelet_frames: int) -> D4RT:
    """A copy of ``model`` whose tubelets span ``tubelet_frames`` frames, a divisor of the current span (see the
    module docstring): ``patch_embed.proj.weight (dim, 3 * k * p * p)`` becomes ``(dim, 3 * k' * p * p)``, its slot
    s' the sum of the old slots s with s % k' == s'; ``pos_embed.time (ceil(max_frames / k), dim)`` becomes
    ``(ceil(max_frames / k'), dim)``, row j the old row j // (k / k'). Raises :class:`UserError` if ``tubelet_frames``
    does not divide the current span or would not shorten it."""
    config = model.config
    k = config.tubelet_frames
    if tubelet_frames < 1 or tubelet_frames >= k or k % tubelet_frames:
        raise UserError(f"with_tubelet_frames shortens tubelets to a divisor of {k} frames, not {tubelet_frames}")
    if config.step_frames != k:
        raise UserError(f"with_tubelet_frames shortens tubelets that do not overlap; this model starts one every "
                        f"{config.step_frames} frames (tubelet_stride)")
    shorter = D4RT(config.replace(tubelet_frames=tubelet_frames))
    state = model.state_dict()
    p, ratio = config.patch_size, k // tubelet_frames
    with torch.no_grad():
        weight = state["encoder.patch_embed.proj.weight"]  # (dim, 3 * k * p * p) in (channel, time, row, col) order
        kernel = weight.reshape(weight.shape[0], 3, ratio, tubelet_frames, p, p).sum(dim=2)
        state["encoder.patch_embed.proj.weight"] = kernel.reshape(weight.shape[0], -1).contiguous()
        rows = torch.arange(shorter.config.max_time_steps) // ratio
        state["encoder.pos_embed.time"] = state["encoder.pos_embed.time"][rows].clone()
    shorter.load_state_dict(state, strict=True)
    return shorter.train(model.training)


def with_tubelet_stride(model: D4RT, tubelet_stride: int) -> D4RT:
    """A copy of ``model`` with a tubelet every ``tubelet_stride`` frames, fewer than the frames between its tubelets
    now (see the module docstring): the patch kernel is kept; ``pos_embed.time`` becomes ``(ceil(max_frames /
    tubelet_stride), dim)``, row j the old row of frame j * tubelet_stride. Raises :class:`UserError` if the stride
    would not shorten the step."""
    config = model.config
    if not 1 <= tubelet_stride < config.step_frames:
        raise UserError(f"with_tubelet_stride starts tubelets more often than every {config.step_frames} frames: "
                        f"{tubelet_stride} does not")
    overlapping = D4RT(config.replace(tubelet_stride=tubelet_stride))
    state = model.state_dict()
    rows = torch.arange(overlapping.config.max_time_steps) * tubelet_stride // config.step_frames
    state["encoder.pos_embed.time"] = state["encoder.pos_embed.time"][rows].clone()
    overlapping.load_state_dict(state, strict=True)
    return overlapping.train(model.training)
