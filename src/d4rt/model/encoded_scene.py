"""EncodedScene: one clip encoded once, answering any number of queries.

This is the thin user-facing layer over the pure modules (as CoTracker's predictor): it checks the
queries, decodes them in chunks of bounded memory without gradients, and caches the per-layer keys and
values of the scene tokens so each chunk only pays for its own queries.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import torch

from d4rt.errors import UserError
from d4rt.model.decoder import SceneKV
from d4rt.model.inputs import check_queries

if TYPE_CHECKING:
    from d4rt.config import D4RTConfig
    from d4rt.model.d4rt import D4RT

OUTPUT_KEYS = ("points", "uv", "visibility", "motion", "normals", "confidence")


def autocast_dtype(device: torch.device) -> torch.dtype | None:
    """The dtype autocast computes in on ``device`` right now, or None when autocast is off there."""
    return torch.get_autocast_dtype(device.type) if torch.is_autocast_enabled(device.type) else None


def free_memory_bytes(device: torch.device) -> int | None:
    """Memory free for new tensors on ``device`` right now: CUDA's free device memory plus what the
    caching allocator holds unused; on the CPU, the available physical memory (None if unknown)."""
    if device.type == "cuda":
        free, _ = torch.cuda.mem_get_info(device)
        return int(free + torch.cuda.memory_reserved(device) - torch.cuda.memory_allocated(device))
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


def decode_bytes_per_query(config: "D4RTConfig", num_tokens: int, element_bytes: int = 4) -> int:
    """Working memory one query needs while decoded (an upper bound, without gradients): the residual
    stream, normalised input, query, attention output and MLP activations of one block, the attention
    scores over ``num_tokens`` scene tokens (in case no fused kernel applies), the RGB patch sampling
    (int64 indices and float32 samples) and the 13 float32 outputs."""
    d, mlp, heads = config.decoder_dim, config.decoder_mlp_dim, config.decoder_heads
    per_block = element_bytes * (6 * d + 2 * mlp + heads * num_tokens)
    patch = config.rgb_patch_size ** 2 * (8 * 4 + 4 * 3 * 3)
    return per_block + patch + 4 * 32


def padded_rows(rows: int, chunk: int) -> int:
    """How many queries a chunk of ``rows`` is decoded as: the next power of two, at most ``chunk``.

    Why: oneDNN (the CPU's bf16 matrix products) builds and keeps a kernel for every matrix shape it meets,
    and a long video's many different last-chunk sizes each added one: measured, about 45 MiB of the peak of
    a 192-frame run. Rounding keeps the shapes to a few; the padding costs at most one chunk's worth per call.
    Used under autocast only: a padded chunk may round its last bits differently, and float32 answers stay
    exactly those of unpadded decoding.
    """
    return min(chunk, 1 << max(rows - 1, 0).bit_length())


def auto_chunk_size(config: "D4RTConfig", num_tokens: int, device: torch.device | str,
                    memory_fraction: float = 0.25, largest: int = 1 << 16) -> int:
    """The largest power-of-two chunk whose decoding fits ``memory_fraction`` of the free memory.

    On a GPU bigger chunks keep the device busy, so up to ``largest``; on the CPU the chunk that fits
    is capped at config ``query_chunk_size`` (past a few thousand queries a CPU gains nothing, and
    the benchmark measures where it stops gaining: ``d4rt bench --chunks ...``).
    """
    device = torch.device(device)
    free = free_memory_bytes(device)
    dtype = autocast_dtype(device)
    per_query = decode_bytes_per_query(config, num_tokens, 2 if dtype in (torch.bfloat16, torch.float16) else 4)
    cap = largest if device.type == "cuda" else config.query_chunk_size
    if free is None:
        return min(cap, config.query_chunk_size)
    fit = max(1, int(free * memory_fraction) // per_query)
    chunk = 1 << (fit.bit_length() - 1)  # round down to a power of two
    return max(1, min(cap, chunk))


class EncodedScene:
    """The Global Scene Representation of one clip, with the inputs queries need.

    Attributes:
        tokens: ``(1, M, encoder_dim)`` scene tokens (tubelets in time, row, column order, then the
            aspect-ratio token).
        num_frames: T, the real frames of the clip (queries index 0..T-1).
        height, width: size of the original frames in pixels.
        aspect_ratio: width / height of the original frames.
        patch_video: ``(1, T, h, w, 3)`` frames the RGB patches are cut from (encoder resolution, or the
            original frames in their own dtype when ``rgb_patch_source == "original"``); None if patches
            are disabled.
    """

    def __init__(self, model: "D4RT", tokens: torch.Tensor, num_frames: int, height: int, width: int,
                 patch_video: torch.Tensor | None):
        self.model = model
        self.tokens = tokens
        self.num_frames = num_frames
        self.height, self.width = height, width
        self.aspect_ratio = width / height
        self.patch_video = patch_video
        self._kv: SceneKV | None = None
        self._kv_dtype: torch.dtype | None = None

    def scene_kv(self, cache: bool = True) -> SceneKV:
        """Per-decoder-layer keys and values of the scene tokens; computed once when ``cache``.

        The cache belongs to the autocast dtype it was projected under (None outside autocast): keys made
        under bf16 autocast are bf16, and a later float32 query would otherwise meet them with a dtype
        error (or, cast up, with answers that differ from an uncached decode).
        """
        if not cache:
            return self.model.decoder.project_scene(self.tokens)
        dtype = autocast_dtype(self.tokens.device)
        if self._kv is None or self._kv_dtype != dtype:
            self._kv, self._kv_dtype = self.model.decoder.project_scene(self.tokens), dtype
        return self._kv

    def clear_cache(self) -> None:
        """Drop the cached keys/values (they are rebuilt on the next query)."""
        self._kv, self._kv_dtype = None, None

    @torch.no_grad()
    def query(self, queries: Any, chunk_size: int | str | None = None, cache_kv: bool | None = None,
              share_sources: bool | None = None) -> dict[str, torch.Tensor]:
        """Decode independent queries.

        Args:
            queries: ``(N, 5)`` float = [u, v, t_src, t_tgt, t_cam]. (u, v) in [0, 1] over the image of
                frame t_src (pixel centres at (i + 0.5) / W); times are integer frame indices in
                [0, num_frames). Anything else raises :class:`UserError`.
            chunk_size: queries decoded at once (default: config ``query_chunk_size``; ``"auto"``: the
                largest that fits the free memory, see :func:`auto_chunk_size`); only memory and speed
                depend on it, never the answers beyond rounding (the matrix products' order of sums, and
                under autocast the bf16 rounding of a padded last chunk, see :func:`padded_rows`).
            cache_kv: reuse the scene keys/values across chunks and calls (default: config
                ``cache_scene_kv``); False recomputes them for every chunk.
            share_sources: consecutive queries with the same (u, v, t_src), such as the T queries of a
                full-video track, compute the source part of their embedding (Fourier features, t_src
                embedding, RGB patch) once; the answers are the same either way. Default: on a CPU only,
                where it is faster (1.07x); on an H200 it was slower (0.76x, its gather costing more than
                the projection it saves: README, GPU figures).

        Returns:
            dict of tensors on the model's device (OpenCV camera: x right, y down, z forward):

            - ``points (N, 3)``: the 3D position at time t_tgt of the surface point seen at (u, v) in
              frame t_src, in the camera coordinates of frame t_cam (the scale the model was trained in).
            - ``uv (N, 2)``: the point's 2D position in frame t_tgt, same normalised (u, v) convention
              (may leave [0, 1]).
            - ``visibility (N,)``: probability that the point is visible in frame t_tgt.
            - ``motion (N, 3)``: the point's 3D displacement from time t_src to t_tgt, in the camera
              coordinates of t_cam.
            - ``normals (N, 3)``: unit surface normal at time t_tgt, camera coordinates of t_cam.
            - ``confidence (N,)``: positive confidence of ``points`` (higher is more certain).
        """
        queries = check_queries(queries, self.num_frames)
        device = self.tokens.device
        queries = queries.to(device=device, dtype=torch.float32)
        chunk = chunk_size if chunk_size is not None else self.model.config.query_chunk_size
        if chunk == "auto":
            chunk = auto_chunk_size(self.model.config, self.tokens.shape[1], device)
        if not isinstance(chunk, int) or isinstance(chunk, bool) or chunk < 1:
            raise UserError(f"chunk_size must be a positive integer or 'auto', got {chunk!r}")
        cache = self.model.config.cache_scene_kv if cache_kv is None else bool(cache_kv)
        if share_sources is None:
            share_sources = device.type == "cpu"

        # The answers go straight into tensors of the final size (allocated once the first chunk gives the
        # shapes and dtypes): keeping per-chunk pieces to concatenate would hold every answer twice at the end.
        # No queries still run one (empty) chunk, so the empty answers have the usual shapes and dtypes.
        n = queries.shape[0]
        outputs: dict[str, torch.Tensor] = {}
        pad = autocast_dtype(device) is not None  # oneDNN's reduced-precision path (see padded_rows)
        for start in range(0, max(n, 1), chunk):
            part = queries[start:start + chunk]
            rows = part.shape[0]
            extra = padded_rows(rows, chunk) - rows if pad and rows else 0
            if extra:  # repeats of the last query, answered and dropped
                part = torch.cat([part, part[-1:].expand(extra, -1)])
            answer = self.model.decode(part[None], self.scene_kv(cache), self.patch_video, share_sources,
                                       tokens_per_step=self.tokens_per_step)
            if not outputs:
                outputs = {key: answer[key].new_empty((n, *answer[key].shape[2:])) for key in OUTPUT_KEYS}
            for key in OUTPUT_KEYS:
                outputs[key][start:start + rows] = answer[key][0, :rows]
        return outputs

    @property
    def tokens_per_step(self) -> int:
        """Tubelet tokens per time step of the scene (rows x columns; the aspect-ratio token excluded)."""
        steps = -(-self.num_frames // self.model.config.step_frames)
        return (self.tokens.shape[1] - 1) // steps

    def __repr__(self) -> str:
        return (f"EncodedScene(frames={self.num_frames}, original={self.width}x{self.height}, "
                f"tokens={tuple(self.tokens.shape)})")
