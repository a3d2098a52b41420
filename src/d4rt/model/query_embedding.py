"""Query embedding: q = (u, v, t_src, t_tgt, t_cam) -> one token.

token = [Fourier(u, v) + E_src[t_src] + RGB-patch(u, v, t_src)] + [E_tgt[t_tgt] + E_cam[t_cam]]   (five terms)

The first bracket (the source part) depends on (u, v, t_src) only: the T queries of a full-video track
share it, so it can be computed once per track and broadcast (``share_sources``).

Conventions: (u, v) in [0, 1] over the image with pixel centres at (i + 0.5) / W; the continuous pixel
position of (u, v) is x = u * W - 0.5, y = v * H - 0.5 (OpenCV: the centre of the top-left pixel is
(0, 0)). Times are 0-indexed frame indices of the real (unpadded) clip.
"""

from __future__ import annotations

import torch
from torch import nn

from d4rt.config import D4RTConfig
from d4rt.model.layers import fourier_features, fourier_frequencies


def sample_rgb_patches(
    video: torch.Tensor,
    uv: torch.Tensor,
    frame: torch.Tensor,
    size: int,
    mean: torch.Tensor,
    std: torch.Tensor,
    sizes: torch.Tensor | None = None,
) -> torch.Tensor:
    """Bilinear, sub-pixel ``size x size`` RGB patches centred at (u, v), normalised.

    Args:
        video: ``(B, T, H, W, 3)``, uint8 (0..255) or float in [0, 1]; stays in its dtype (only the
            sampled pixels are converted, so an original-resolution uint8 video costs no extra memory).
        uv: ``(B, N, 2)`` query positions in [0, 1].
        frame: ``(B, N)`` integer frame index into T of each query.
        size: patch side in pixels of ``video``; samples are 1 pixel apart, centred on (u, v).
        mean, std: ``(3,)`` pixel normalisation applied to each sample.
        sizes: ``(B, 2)`` integer (h, w) of each clip's frames when ``video`` holds clips of different sizes,
            each padded (at the bottom and right) to the batch's largest; pixels beyond a clip's own size are
            outside its image. None: every clip fills ``video``.

    Returns:
        ``(B, N, size, size, 3)`` float32: ``(pixel - mean) / std``, rows top to bottom. Samples that
        fall outside the image read as 0 (the mean colour); bilinear weights of outside neighbours are
        dropped, not renormalised, so an edge fades to the mean colour.
    """
    b, t, height, width, _ = video.shape
    device = video.device
    if sizes is None:
        h, w = height, width
    else:  # each clip's own size, (B, 1) to broadcast over its queries
        sizes = sizes.to(device)
        h, w = sizes[:, :1], sizes[:, 1:]
    # Samples are whole pixels apart, so every sample of a patch has the same sub-pixel offset: gather
    # one (size + 1)^2 window per query and blend its four shifted copies with two scalar weights
    # (a third of the reads of blending each sample's own four neighbours).
    x = uv[..., 0].float() * w - 0.5 - (size - 1) / 2  # (B, N) left sample column
    y = uv[..., 1].float() * h - 0.5 - (size - 1) / 2  # (B, N) top sample row
    x0, y0 = x.floor(), y.floor()
    fx, fy = (x - x0)[..., None, None, None], (y - y0)[..., None, None, None]
    steps = torch.arange(size + 1, device=device)
    cols = x0.long()[..., None] + steps  # (B, N, size + 1)
    rows = y0.long()[..., None] + steps
    if sizes is None:
        inside_rows, inside_cols = (rows >= 0) & (rows < h), (cols >= 0) & (cols < w)
        rows, cols = rows.clamp(0, h - 1), cols.clamp(0, w - 1)
    else:
        h, w = h[..., None], w[..., None]  # (B, 1, 1)
        inside_rows, inside_cols = (rows >= 0) & (rows < h), (cols >= 0) & (cols < w)
        rows, cols = torch.minimum(rows.clamp(min=0), h - 1), torch.minimum(cols.clamp(min=0), w - 1)
    base = (torch.arange(b, device=device)[:, None] * t + frame.long()) * (height * width)  # (B, N)
    row_start = base[..., None] + rows * width  # (B, N, size + 1)
    index = row_start[..., :, None] + cols[..., None, :]  # (B, N, size + 1, size + 1)
    window = video.reshape(b * t * height * width, 3).index_select(0, index.reshape(-1)).reshape(*index.shape, 3)
    window = window.float()
    scale = 255.0 if video.dtype == torch.uint8 else 1.0
    mean, std = mean.to(device, torch.float32), std.to(device, torch.float32)
    inside = inside_rows[..., :, None] & inside_cols[..., None, :]
    if device.type != "cpu" or not bool(inside.all()):  # (a host sync is cheap on the CPU only)
        # Outside the image: the mean colour, which normalises to 0. Blending before normalising is the
        # same affine map, with one pass over the smaller blended patch instead of three over the window.
        window = torch.where(inside[..., None], window, mean * scale)
    top = torch.lerp(window[..., :-1, :, :], window[..., 1:, :, :], fy)
    patch = torch.lerp(top[..., :-1, :], top[..., 1:, :], fx)
    return torch.addcmul(-mean / std, patch, 1.0 / (scale * std))  # (pixel / scale - mean) / std


class QueryEmbedding(nn.Module):
    """``forward(queries: (B, N, 5), patch_video: (B, T, H, W, 3) | None) -> (B, N, decoder_dim)``.

    ``queries`` columns are [u, v, t_src, t_tgt, t_cam], already validated (u, v in [0, 1], times
    integer frame indices < T). ``patch_video`` is where the RGB patch is cut from (the encoder-resolution
    or the original video); it may be None only when ``rgb_patch_size`` is 0.

    Fourier features: (u, v) themselves plus sin/cos at ``fourier_frequencies`` frequencies log-spaced
    from 1 cycle per image to ``fourier_max`` (default: the encoder's Nyquist frequency, image_size / 2).
    """

    def __init__(self, config: D4RTConfig):
        super().__init__()
        self.config = config
        dim = config.decoder_dim
        # Derived from the config, so not saved in checkpoints.
        self.register_buffer("frequencies", fourier_frequencies(config.fourier_frequencies, config.fourier_max),
                             persistent=False)
        self.register_buffer("pixel_mean", torch.tensor(config.pixel_mean), persistent=False)
        self.register_buffer("pixel_std", torch.tensor(config.pixel_std), persistent=False)
        self.fourier_proj = nn.Linear(2 + 4 * config.fourier_frequencies, dim)
        self.time_src = nn.Embedding(config.max_frames, dim)
        self.time_tgt = nn.Embedding(config.max_frames, dim)
        self.time_cam = nn.Embedding(config.max_frames, dim)
        p = config.rgb_patch_size
        self.patch_proj = nn.Linear(3 * p * p, dim) if p > 0 else None

    def source_tokens(self, queries: torch.Tensor, patch_video: torch.Tensor | None,
                      patch_sizes: torch.Tensor | None = None) -> torch.Tensor:
        """The part of the token that depends on (u, v, t_src) only: ``Fourier(u, v) + E_src[t_src] +
        RGB-patch(u, v, t_src)``. ``queries: (B, N, >= 3)`` -> ``(B, N, decoder_dim)``; ``patch_sizes (B, 2)``:
        each clip's (h, w) in a padded ``patch_video`` (:func:`sample_rgb_patches` ``sizes``)."""
        uv = queries[..., :2]
        t_src = queries[..., 2].round().long()
        # Features in float32 (phase precision), then the projection's own dtype (bf16 for a bf16 model).
        token = self.fourier_proj(fourier_features(uv, self.frequencies).to(self.fourier_proj.weight.dtype))
        token = token + self.time_src(t_src)
        if self.patch_proj is not None:
            if patch_video is None:
                raise ValueError("rgb_patch_size > 0 needs the video to cut patches from")
            patch = sample_rgb_patches(patch_video, uv, t_src, self.config.rgb_patch_size,
                                       self.pixel_mean, self.pixel_std, patch_sizes)
            token = token + self.patch_proj(patch.flatten(-3).to(self.patch_proj.weight.dtype))
        return token

    def time_tokens(self, queries: torch.Tensor) -> torch.Tensor:
        """The part that depends on (t_tgt, t_cam) only: ``E_tgt[t_tgt] + E_cam[t_cam]``;
        ``queries: (B, N, 5)`` -> ``(B, N, decoder_dim)``."""
        return self.time_tgt(queries[..., 3].round().long()) + self.time_cam(queries[..., 4].round().long())

    def forward(self, queries: torch.Tensor, patch_video: torch.Tensor | None,
                share_sources: bool = False, patch_sizes: torch.Tensor | None = None) -> torch.Tensor:
        """Query tokens ``(B, N, decoder_dim)`` = source part + time part.

        ``share_sources``: consecutive queries with the same (u, v, t_src) (a track's queries, which differ
        only in t_tgt and t_cam) compute the source part (Fourier features, t_src embedding, RGB patch
        and its projection) once and broadcast it. Runs are found in one pass (no sort), so queries laid
        out source-major, as every recipe does, share fully; the answers equal the unshared ones.
        """
        if share_sources:
            shared = self._shared_source_tokens(queries, patch_video, patch_sizes)
            if shared is not None:
                return shared + self.time_tokens(queries)
        return self.source_tokens(queries, patch_video, patch_sizes) + self.time_tokens(queries)

    def _shared_source_tokens(self, queries: torch.Tensor, patch_video: torch.Tensor | None,
                              patch_sizes: torch.Tensor | None) -> torch.Tensor | None:
        """Source part computed once per run of equal (u, v, t_src), or None when no run has two queries."""
        b, n, _ = queries.shape
        if n < 2:
            return None
        flat = queries.reshape(b * n, -1)[:, :3]
        starts = torch.ones(b * n, dtype=torch.bool, device=queries.device)
        starts[1:] = (flat[1:] != flat[:-1]).any(-1)
        starts[::n] = True  # a run never crosses from one clip of the batch into the next
        runs = int(starts.sum())
        if runs == b * n:
            return None
        first = starts.nonzero().squeeze(-1)  # (runs,) index of each run's first query
        run_of = torch.cumsum(starts, 0) - 1  # (B * N,) the run each query belongs to
        if b == 1:
            tokens = self.source_tokens(flat[first][None], patch_video, patch_sizes)[0]
        else:  # each clip's runs against its own frames
            clip = first // n
            tokens = torch.cat([self.source_tokens(flat[first[clip == i]][None],
                                                   None if patch_video is None else patch_video[i:i + 1],
                                                   None if patch_sizes is None else patch_sizes[i:i + 1])[0]
                                for i in range(b)])
        return tokens[run_of].reshape(b, n, -1)
