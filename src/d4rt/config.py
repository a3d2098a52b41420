"""D4RTConfig: every architectural number of the model in one dataclass, plus the named presets.

The paper (Zhang et al., arXiv 2512.08924) fixes some numbers (ViT-g encoder of 40 layers, 2x16x16
tubelets, 256x256 input, 48 frames, 8-layer decoder of about 144M parameters, 9x9 RGB patch); every
number it leaves open is a field here with the value we chose and why (see also docs/model.md).

Presets:

=======  =======  ======  ==========  =====================  ==========================
name     input    frames  tubelet     encoder (w/d/h/mlp)    decoder (w/d/h/mlp)
=======  =======  ======  ==========  =====================  ==========================
tiny     64       24      2x8x8       192/6/3/768            192/4/3/768
small    128      32      2x8x8       256/8/4/1024           256/4/4/1024
base     256      48      2x16x16     768/12/12/3072 ViT-B   512/6/8/2048
large    256      48      2x16x16     1024/24/16/4096 ViT-L  768/6/12/3072
huge     256      48      2x16x16     1280/32/16/5120 ViT-H  1024/6/16/4096
giant    256      48      2x16x16     1408/40/16/6144 ViT-g  1152/8/18/5184
=======  =======  ======  ==========  =====================  ==========================

``d4rt info --preset NAME`` prints the parameter counts of each.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from d4rt.errors import UserError

# Which camera each frame's pose is fitted against (Reconstruction's ``pose_pairs``): "first", the paper's
# recipe, fits frame i against the window's first camera; "adjacent" fits it against frame i - 1 and chains the
# fits, so every query's t_src - t_cam gap is 1 (a learned model's error grows with that gap) at the price of
# drift along the chain. "graph" fits frame i against frames i - 1, i - 2, i - 4, ... (GRAPH_GAPS, inside the
# window) and solves every pose at once by least squares over all those fits (rotation averaging, then the
# positions): short gaps keep a chain's accuracy while the long ones bound its drift, for GRAPH_GAPS times the
# camera queries. All three are exact on the oracle. Here, in the torch-free foundation, so that the command line
# and the model config share one list.
POSE_PAIRS = ("first", "adjacent", "graph")
GRAPH_GAPS = (1, 2, 4, 8, 16)


def check_pose_pairs(pairs: str, name: str = "pose_pairs") -> str:
    """``pairs`` if it names a pose pairing, else a one-line :class:`UserError` naming the setting ``name``."""
    if pairs not in POSE_PAIRS:
        raise UserError(f"{name} must be one of {', '.join(POSE_PAIRS)}, got {pairs!r}")
    return pairs


# Moving-object masks (d4rt.reconstruction.motion; here, torch-free, for the command line's help and checks): the
# frames of its window each pixel is compared with, spread from the window's first to its last frame, and the
# fraction of its depth a surface must travel to be called moving: far above the oracle's rounding (1e-6), below
# the slowest body the synthetic engine moves over a window.
MOTION_TARGETS = 5
MOTION_THRESHOLD = 0.05


def check_motion_options(threshold: float, targets: int) -> None:
    """One-line :class:`UserError` s for moving-object mask options the recipe cannot use."""
    if isinstance(threshold, bool) or not (isinstance(threshold, numbers.Real) and math.isfinite(threshold)
                                           and threshold > 0):
        raise UserError(f"the motion threshold must be a finite number > 0 (a fraction of depth), got {threshold!r}")
    if isinstance(targets, bool) or not isinstance(targets, numbers.Integral) or targets < 2:
        raise UserError(f"the number of motion target frames must be an integer >= 2, got {targets!r}")


PATCH_SOURCES = ("encoder", "original")
CONFIDENCE_ACTIVATIONS = ("softplus", "one_plus_exp")
# How the points head's 3 numbers become a point (ModelConfig.points_activation).
POINTS_ACTIVATIONS = ("linear", "exp")


@dataclass(frozen=True)
class D4RTConfig:
    """Architecture of a D4RT model. Build one with :meth:`preset` (optionally overriding fields).

    Video input
        image_size: side of the square the video is resized to before the encoder (pixels).
        max_frames: most frames one clip may have; longer videos must be cut into windows.
        patch_size: spatial side of one tubelet (pixels at ``image_size``).
        tubelet_frames: frames per tubelet. A clip whose length is not a multiple of it is padded by
            repeating its last frame (the padding is never queryable).
        tubelet_stride: frames between the starts of consecutive tubelets; None (the paper's) is
            ``tubelet_frames``, tubelets that do not overlap. Less overlaps them: 1 gives every frame its own
            tokens, each tubelet holding its frame and the next (the last frame repeated past the clip's
            end), so that a token still sees the motion between frames. The encoder's tokens grow by
            ``tubelet_frames / tubelet_stride``.
        pixel_mean, pixel_std: per-channel RGB normalisation of [0, 1] pixels. ImageNet statistics,
            which VideoMAE v2 was pre-trained with, so converted weights see the inputs they expect.

    Encoder (a ViT over all tubelets of the clip)
        encoder_dim, encoder_depth, encoder_heads, encoder_mlp_dim: the ViT's width, number of blocks,
            attention heads and MLP hidden width.
        global_attention_every: block i (0-indexed) attends over the whole clip when
            ``(i + 1) % global_attention_every == 0`` and within one tubelet time step otherwise.
            2 alternates frame-local and global blocks as VGGT does (not in paper). At most
            ``encoder_depth``: an encoder without a global block would leave the aspect-ratio token
            unattended and the frames unconnected.

    Query embedding
        fourier_frequencies: number of Fourier frequencies per axis of (u, v) (not in paper).
        fourier_max_frequency: highest frequency in cycles per image side; frequencies are
            log-spaced from 1 to it. None means ``image_size / 2``: the Nyquist frequency of the
            encoder input, so the finest feature oscillates once per 2 encoder pixels and nothing is
            numerical noise (not in paper).
        rgb_patch_size: side of the RGB patch around (u, v) in source pixels (paper: 9; 0 disables).
        rgb_patch_source: ``"encoder"`` samples the patch from the resized encoder-resolution video
            (paper default), ``"original"`` from the original frames (sharper edges, App. C).

    Decoder (cross-attention from each query to the scene tokens, then an MLP; no query-query mixing)
        decoder_dim, decoder_depth, decoder_heads, decoder_mlp_dim: as for the encoder.
        confidence_activation: ``"softplus"`` (c = softplus(x), any positive value) or
            ``"one_plus_exp"`` (c = 1 + exp(x), DUSt3R's choice, c >= 1) (not in paper).
        points_activation: ``"linear"`` (the head's 3 numbers r are the point, the paper leaves it open) or
            ``"exp"`` (the point is ``r / |r| * (exp(|r|) - 1)``: the direction from r, the distance from its
            exponential, DUSt3R's ``exp`` depth mode; not in paper). Why: the loss compares log-compressed points,
            and a sky 50 m away beside a box at 1 m asks a linear head for outputs 50 times apart, which its
            LayerNorm'd features and weight decay resist; every tiny model trained with it put the far range 6-17
            times the near one whatever the truth (docs/training.md, stages 21, 64, 67). Under ``"exp"`` a ratio
            of depths is a difference of the head's outputs. Measured (stages 77-78): trained on from the shipped
            weights (converted by tools/convert_points_activation.py) no better than linear at equal steps, so
            linear in every shipped config; kept for models trained from scratch (not measured).
        relative_pose_head: the points head answers in camera t_src and a per-query relative-pose head
            (rotation in the 6D form, translation) moves them, and motion and normals, into camera t_cam;
            identity where t_cam = t_src (not in paper, which regresses the point in camera t_cam
            directly). Why: a rotation applied to a point is bilinear in (pose, point), which an MLP
            approximates poorly; every tiny model trained on the CPU without it ignored t_cam entirely
            (docs/training.md). Its layer is initialised like every other linear layer: started at zero
            (the identity pose) it stayed near zero and passed no gradient back to the encoder.
        uv_residual: the 2D head answers the displacement from the query's own (u, v): ``uv = (u, v) + head``
            (not in paper, which leaves the parameterisation open). Why: the plain head must rebuild (u, v)
            from the Fourier features before it can move it; stage 41's weights answered a pixel's own frame
            1.3 pixels off and moved pixels no better than leaving them where they were (docs/training.md,
            stage 42), so correspondence never showed in the 2D term's gradient. Measured (stage 43): no better
            than the plain head over 1,000 steps, so off in every shipped config; kept for longer or larger runs.
        dense_depth_head: add :class:`d4rt.model.dense_depth.DenseDepthHead`, a training aid that answers every
            pixel's log-depth from the scene tokens so that ``loss.weight_dense_depth`` can supervise the encoder
            at every pixel (not in paper; inference never uses it). Why: the queries alone leave the sky and a
            near box at nearly one depth in the tiny models trained so far (docs/training.md, stage 67).
        target_frame_heads: the first this many heads of every decoder cross-attention attend only to the scene
            tokens of the query's t_tgt time step (not in paper; 0 = off). Why: the trained tiny models' decoders
            spread their attention over every time step alike although the tokens carry their time step, so no
            query reads the frame it asks about and their tracks do not follow their points (docs/training.md,
            stages 79-81). No parameters are added; a checkpoint trained without it can be trained on with it.
            Measured (stage 81, one head, 1,200 steps from the shipped weights): the head looks only at the right
            frame but finds the point's old image position there, and the answers did not improve, so off in every
            shipped config; kept for models trained from scratch or with pretrained features (not measured).

    Inference default
        pose_pairs: the camera recipe's pairing that ``Reconstruction.from_model`` uses for this model when the
            caller names none: ``"first"`` (the paper's: each frame against the window's first camera) or
            ``"adjacent"`` (against the previous frame, the fits chained) or ``"graph"`` (against frames
            i - 1, i - 2, i - 4, ..., every pose solved at once); see ``POSE_PAIRS``. Saved with the
            weights because it is chosen per model, on held-out clips; not part of the architecture.
        flip_average: answer every query on the video and on its left-right mirror and average the two
            (:mod:`d4rt.reconstruction.flip_average`; not in paper): two encoder passes and twice the queries
            for answers with less of the model's own error. Saved with the weights for the same reason.
        motion_threshold: the fraction of its depth a surface must travel to be called moving by
            ``Reconstruction.motion_masks`` (:mod:`d4rt.reconstruction.motion`) when the caller names none: a
            model's static points wander by its own error, so each model carries the threshold measured for it on
            held-out clips (``tools/motion_mask_probe.py``); the oracle's default is ``MOTION_THRESHOLD``.

    Runtime
        layer_norm_eps: epsilon of every LayerNorm (1e-6, as VideoMAE v2).
        init_std: standard deviation of the truncated-normal initialisation of linear layers.
        gradient_checkpointing: recompute encoder and decoder blocks in the backward pass (training only).
        query_chunk_size: queries decoded at once by ``EncodedScene.query`` (bounds memory).
        cache_scene_kv: project the scene tokens to keys/values once per decoder layer and reuse them
            for every query chunk; False recomputes them per chunk (for benchmarks).
    """

    name: str = "custom"
    # video input
    image_size: int = 64
    max_frames: int = 24
    patch_size: int = 8
    tubelet_frames: int = 2
    tubelet_stride: int | None = None
    pixel_mean: tuple[float, float, float] = (0.485, 0.456, 0.406)
    pixel_std: tuple[float, float, float] = (0.229, 0.224, 0.225)
    # encoder
    encoder_dim: int = 192
    encoder_depth: int = 6
    encoder_heads: int = 3
    encoder_mlp_dim: int = 768
    global_attention_every: int = 2
    # query embedding
    fourier_frequencies: int = 8
    fourier_max_frequency: float | None = None
    rgb_patch_size: int = 9
    rgb_patch_source: str = "encoder"
    # decoder
    decoder_dim: int = 192
    decoder_depth: int = 4
    decoder_heads: int = 3
    decoder_mlp_dim: int = 768
    confidence_activation: str = "softplus"
    points_activation: str = "linear"
    relative_pose_head: bool = False
    uv_residual: bool = False
    dense_depth_head: bool = False
    target_frame_heads: int = 0
    # inference default
    pose_pairs: str = "first"
    flip_average: bool = False
    motion_threshold: float = MOTION_THRESHOLD
    # runtime
    layer_norm_eps: float = 1e-6
    init_std: float = 0.02
    gradient_checkpointing: bool = False
    query_chunk_size: int = 4096
    cache_scene_kv: bool = True

    def __post_init__(self) -> None:
        # JSON gives lists; keep tuples so configs compare equal after a round trip.
        for name in ("pixel_mean", "pixel_std"):
            object.__setattr__(self, name, _rgb_triple(name, getattr(self, name)))
        self.validate()

    # ----------------------------------------------------------------------------------------- checks
    def validate(self) -> None:
        """Raise :class:`UserError` naming the first inconsistent field."""
        if not isinstance(self.name, str):
            raise UserError(f"config field name must be a string, got {self.name!r}")
        positive = ["image_size", "max_frames", "patch_size", "tubelet_frames", "encoder_dim",
                    "encoder_depth", "encoder_heads", "encoder_mlp_dim", "global_attention_every",
                    "fourier_frequencies", "decoder_dim", "decoder_depth", "decoder_heads",
                    "decoder_mlp_dim", "query_chunk_size"]
        for name in positive:
            value = getattr(self, name)
            if not _is_int(value) or value < 1:
                raise UserError(f"config field {name} must be a positive integer, got {value!r}")
        if self.global_attention_every > self.encoder_depth:
            # No global block: frames never exchange information and nothing attends to the aspect token.
            raise UserError(f"config global_attention_every {self.global_attention_every} exceeds encoder_depth "
                            f"{self.encoder_depth}: the encoder would have no global-attention block")
        if self.tubelet_stride is not None and not (
                _is_int(self.tubelet_stride) and 1 <= self.tubelet_stride <= self.tubelet_frames):
            raise UserError(f"config tubelet_stride must be null or an integer in 1-{self.tubelet_frames} "
                            f"(tubelet_frames), got {self.tubelet_stride!r}")
        if self.dense_depth_head and self.step_frames != self.tubelet_frames:
            raise UserError("config dense_depth_head answers each tubelet's own pixels: it needs tubelets that do not "
                            f"overlap (tubelet_stride null or {self.tubelet_frames}), got {self.tubelet_stride}")
        if self.image_size % self.patch_size:
            raise UserError(f"config image_size {self.image_size} is not a multiple of patch_size {self.patch_size}")
        for part in ("encoder", "decoder"):
            dim, heads = getattr(self, f"{part}_dim"), getattr(self, f"{part}_heads")
            if dim % heads:
                raise UserError(f"config {part}_dim {dim} is not divisible by {part}_heads {heads}")
        if not _is_int(self.rgb_patch_size) or self.rgb_patch_size < 0:
            raise UserError(f"config rgb_patch_size must be an integer >= 0, got {self.rgb_patch_size!r}")
        if self.rgb_patch_source not in PATCH_SOURCES:
            raise UserError(f"config rgb_patch_source must be one of {PATCH_SOURCES}, got {self.rgb_patch_source!r}")
        if self.confidence_activation not in CONFIDENCE_ACTIVATIONS:
            raise UserError(
                f"config confidence_activation must be one of {CONFIDENCE_ACTIVATIONS}, got {self.confidence_activation!r}")
        if self.points_activation not in POINTS_ACTIVATIONS:
            raise UserError(
                f"config points_activation must be one of {POINTS_ACTIVATIONS}, got {self.points_activation!r}")
        if self.fourier_max_frequency is not None and not (
                _is_number(self.fourier_max_frequency) and self.fourier_max_frequency >= 1.0):
            raise UserError(f"config fourier_max_frequency must be >= 1 cycle per image, got {self.fourier_max_frequency!r}")
        for name in ("layer_norm_eps", "init_std"):
            value = getattr(self, name)
            if not _is_number(value) or not value > 0:
                raise UserError(f"config field {name} must be a positive number, got {value!r}")
        for name in ("gradient_checkpointing", "cache_scene_kv", "relative_pose_head", "uv_residual",
                     "dense_depth_head", "flip_average"):
            if not isinstance(getattr(self, name), bool):
                raise UserError(f"config field {name} must be true or false, got {getattr(self, name)!r}")
        if not _is_int(self.target_frame_heads) or not 0 <= self.target_frame_heads <= self.decoder_heads:
            raise UserError(f"config target_frame_heads must be an integer in 0-{self.decoder_heads} (decoder_heads), "
                            f"got {self.target_frame_heads!r}")
        check_pose_pairs(self.pose_pairs, "config pose_pairs")
        if not _is_number(self.motion_threshold) or not (math.isfinite(self.motion_threshold)
                                                         and self.motion_threshold > 0):
            raise UserError(f"config motion_threshold must be a finite number > 0, got {self.motion_threshold!r}")
        if min(self.pixel_std) <= 0:
            raise UserError(f"config pixel_std must be positive, got {list(self.pixel_std)}")

    # ------------------------------------------------------------------------------------ derived sizes
    @property
    def patches_from_original(self) -> bool:
        """Query RGB patches are cut from the original-resolution frames (a training sample must carry them)."""
        return self.rgb_patch_size > 0 and self.rgb_patch_source == "original"

    @property
    def grid_size(self) -> int:
        """Tubelets per side of the encoder input: ``image_size // patch_size``."""
        return self.image_size // self.patch_size

    @property
    def step_frames(self) -> int:
        """Frames between consecutive tubelet time steps: ``tubelet_stride``, or ``tubelet_frames`` when it is None.
        Frame t's tokens are those of time step ``t // step_frames``."""
        return self.tubelet_frames if self.tubelet_stride is None else self.tubelet_stride

    @property
    def max_time_steps(self) -> int:
        """Tubelet time steps of the longest clip: ``ceil(max_frames / step_frames)``."""
        return -(-self.max_frames // self.step_frames)

    @property
    def fourier_max(self) -> float:
        """The highest Fourier frequency actually used, in cycles per image side."""
        return float(self.fourier_max_frequency) if self.fourier_max_frequency is not None else self.image_size / 2

    def num_scene_tokens(self, num_frames: int) -> int:
        """Scene tokens for a clip of ``num_frames`` frames at full resolution (+1 aspect-ratio token)."""
        steps = -(-num_frames // self.step_frames)
        return steps * self.grid_size**2 + 1

    # ---------------------------------------------------------------------------------------- presets
    @classmethod
    def preset_names(cls) -> list[str]:
        return list(_PRESETS)

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> "D4RTConfig":
        """The named preset (tiny, small, base, large, huge, giant), with any field overridden."""
        if name not in _PRESETS:
            raise UserError(f"unknown preset {name!r}; choose one of {', '.join(_PRESETS)}")
        return dataclasses.replace(_PRESETS[name], **_checked_fields(overrides))

    def replace(self, **overrides: Any) -> "D4RTConfig":
        """A copy with the given fields changed."""
        return dataclasses.replace(self, **_checked_fields(overrides))

    # ----------------------------------------------------------------------------------------- JSON
    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["pixel_mean"] = list(self.pixel_mean)
        data["pixel_std"] = list(self.pixel_std)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "D4RTConfig":
        if not isinstance(data, dict):
            raise UserError(f"a D4RT config must be a JSON object, got {type(data).__name__}")
        return cls(**_checked_fields(data))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True) + "\n"

    @classmethod
    def from_json(cls, text: str) -> "D4RTConfig":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise UserError(f"config is not valid JSON: {err}") from None
        return cls.from_dict(data)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> "D4RTConfig":
        path = Path(path)
        if not path.is_file():
            raise UserError(f"config file not found: {path}")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            raise UserError(f"cannot read config file {path}: {err}") from None
        try:
            return cls.from_json(text)
        except UserError as err:
            raise UserError(f"{path}: {err}") from None


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)  # JSON true is not a size


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _rgb_triple(name: str, value: Any) -> tuple[float, float, float]:
    """Three finite numbers (one per RGB channel) as a tuple of floats."""
    if not isinstance(value, (list, tuple)) or len(value) != 3 or not all(_is_number(x) for x in value):
        raise UserError(f"config field {name} must be 3 numbers (R, G, B), got {value!r}")
    return tuple(float(x) for x in value)


def _checked_fields(values: dict[str, Any]) -> dict[str, Any]:
    known = {f.name for f in dataclasses.fields(D4RTConfig)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise UserError(f"unknown D4RT config field(s): {', '.join(unknown)}")
    return dict(values)


def _paper_size(name: str, dim: int, depth: int, heads: int, mlp: int,
                dec_dim: int, dec_depth: int, dec_heads: int, dec_mlp: int, freqs: int = 16) -> D4RTConfig:
    """A paper-scale preset: 256x256 input, 48 frames, 2x16x16 tubelets (the paper's numbers)."""
    return D4RTConfig(
        name=name, image_size=256, max_frames=48, patch_size=16, tubelet_frames=2,
        encoder_dim=dim, encoder_depth=depth, encoder_heads=heads, encoder_mlp_dim=mlp,
        fourier_frequencies=freqs,
        decoder_dim=dec_dim, decoder_depth=dec_depth, decoder_heads=dec_heads, decoder_mlp_dim=dec_mlp,
        query_chunk_size=2048,
    )


_PRESETS: dict[str, D4RTConfig] = {
    # CPU-trainable sizes: small input, 8-pixel tubelets so the token grid is still 8x8 / 16x16.
    "tiny": D4RTConfig(name="tiny"),
    "small": D4RTConfig(
        name="small", image_size=128, max_frames=32, patch_size=8, tubelet_frames=2,
        encoder_dim=256, encoder_depth=8, encoder_heads=4, encoder_mlp_dim=1024,
        fourier_frequencies=10,
        decoder_dim=256, decoder_depth=4, decoder_heads=4, decoder_mlp_dim=1024,
    ),
    # Paper sizes: encoders are the standard ViT-B/L/H/g (as in VideoMAE v2). The paper's ablations use
    # a 6-layer decoder; its width is not given, so it grows with the encoder.
    "base": _paper_size("base", 768, 12, 12, 3072, 512, 6, 8, 2048),
    "large": _paper_size("large", 1024, 24, 16, 4096, 768, 6, 12, 3072),
    "huge": _paper_size("huge", 1280, 32, 16, 5120, 1024, 6, 16, 4096),
    # The main model: ViT-g encoder (~1.01B) and an 8-layer decoder. Width 1152 = 18 heads of 64 with
    # MLP 5184 (4.5x) lands the decoder at ~144M parameters, the paper's figure (docs/model.md).
    "giant": _paper_size("giant", 1408, 40, 16, 6144, 1152, 8, 18, 5184),
}
