"""The query decoder D: cross-attention (query -> scene tokens) + MLP blocks, then prediction heads.

There is no self-attention between queries (the paper found it hurts badly): every operation is either
per-query or attention from one query to the fixed scene tokens, so a query's answer never depends on
which other queries are decoded with it. The scene tokens enter each block only through that block's
key/value projection, which :meth:`QueryDecoder.project_scene` computes once per clip.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model.layers import MLP, CrossAttention, FrameRestriction, run_block

# Channels of the raw head output, in order (13 numbers per query, as in the paper).
HEAD_CHANNELS = {"points": 3, "uv": 2, "visibility_logit": 1, "motion": 3, "normals": 3, "confidence": 1}

SceneKV = list[tuple[torch.Tensor, torch.Tensor]]


class CrossAttentionBlock(nn.Module):
    """``x + cross_attn(norm1(x), scene)`` then ``x + mlp(norm2(x))``; ``x: (B, N, dim)``."""

    def __init__(self, dim: int, context_dim: int, heads: int, mlp_dim: int, eps: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=eps)
        self.attn = CrossAttention(dim, context_dim, heads)
        self.norm2 = nn.LayerNorm(dim, eps=eps)
        self.mlp = MLP(dim, mlp_dim)

    def forward(self, x: torch.Tensor, keys: torch.Tensor, values: torch.Tensor,
                frame: FrameRestriction | None = None) -> torch.Tensor:
        x = x + self.attn(self.norm1(x), keys, values, frame)
        return x + self.mlp(self.norm2(x))


def _fresh(x: torch.Tensor) -> torch.Tensor:
    """``x`` itself, or a copy of it when it is a view of another tensor."""
    return x if x._base is None else x.clone()


def rotation_from_6d(d6: torch.Tensor) -> torch.Tensor:
    """Rotation matrices ``(..., 3, 3)`` from the 6D form ``(..., 6)`` (Zhou et al. 2019): the two
    3-vectors are Gram-Schmidt orthonormalised into the first two columns, the third is their cross
    product. Continuous, unlike quaternions or Euler angles, so a regression target without seams."""
    b1 = F.normalize(d6[..., :3], dim=-1, eps=1e-6)
    a2 = d6[..., 3:]
    b2 = F.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1, eps=1e-6)
    return torch.stack([b1, b2, torch.linalg.cross(b1, b2)], dim=-1)


def exp_distance(raw: torch.Tensor) -> torch.Tensor:
    """``raw / |raw| * (exp(|raw|) - 1)`` over the last axis (..., 3): the direction kept, the length exponentiated.

    Written as ``raw * expm1(n) / n`` with ``expm1(n) / n -> 1`` at ``n = 0``, so that a zero vector maps to zero
    with a finite gradient. The length is clamped at 80 before the exponential (float32 overflows near 88):
    an overflow guard, not a range limit (e^80 is 10^34 times the unit).
    """
    length = torch.linalg.vector_norm(raw, dim=-1, keepdim=True)
    tiny = length < 1e-6
    safe = torch.where(tiny, torch.ones_like(length), length)
    gain = torch.where(tiny, 1.0 + 0.5 * length, torch.expm1(safe.clamp(max=80.0)) / safe)
    return raw * gain


# The 6D form of the identity rotation: the relative-pose head's output is added to it.
_IDENTITY_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)


class PredictionHeads(nn.Module):
    """Final LayerNorm and one linear head per output, then each output's activation.

    ``forward(x: (B, N, dim), same_camera: (B, N) bool | None) -> dict`` of (B, N, ...) float32 tensors:
        points (3): raw, or ``exp_distance`` of it (config ``points_activation``). uv (2): raw (a point may leave
        the image). visibility_logit (1 -> squeezed) and visibility = sigmoid(logit). motion (3): raw. normals (3):
        L2-normalised.
        confidence (1 -> squeezed): positive, softplus or 1 + exp (config ``confidence_activation``).

    With ``relative_pose_head`` the points, motion and normals heads answer in camera t_src and a
    ninth-channel head (6D rotation offset from the identity, then translation) maps them into camera
    t_cam: ``points = R p + t``, ``motion = R m``, ``normals = R n``; queries with ``same_camera``
    (t_cam = t_src, which ``same_camera`` must then give) keep R = I, t = 0 exactly. R and t are also
    returned, as ``relative_rotation (B, N, 3, 3)`` and ``relative_translation (B, N, 3)`` (for the
    optional pose loss, :class:`d4rt.training.losses.LossConfig` ``weight_pose``).

    Computed in float32 whatever the autocast or parameter dtype: 13 numbers per query cost nothing, while
    bf16's 8-bit mantissa would round a depth of 10 to steps of 1/16 and quantise every loss input.
    """

    def __init__(self, dim: int, eps: float, confidence_activation: str, relative_pose_head: bool = False,
                 points_activation: str = "linear"):
        super().__init__()
        self.points_activation = points_activation
        self.norm = nn.LayerNorm(dim, eps=eps)
        self.heads = nn.ModuleDict({name: nn.Linear(dim, size) for name, size in HEAD_CHANNELS.items()})
        self.confidence_activation = confidence_activation
        self.relative_pose = nn.Linear(dim, 9) if relative_pose_head else None

    def forward(self, x: torch.Tensor, same_camera: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        with torch.autocast(device_type=x.device.type, enabled=False):
            x = F.layer_norm(x.float(), self.norm.normalized_shape, self.norm.weight.float(),
                             self.norm.bias.float(), self.norm.eps)
            raw = {name: F.linear(x, head.weight.float(), head.bias.float()) for name, head in self.heads.items()}
            if self.points_activation == "exp":  # in camera t_src, before any relative pose moves the point
                raw["points"] = exp_distance(raw["points"])
            if self.relative_pose is not None:
                if same_camera is None:
                    raise ValueError("relative_pose_head needs same_camera (t_cam == t_src per query)")
                pose = F.linear(x, self.relative_pose.weight.float(), self.relative_pose.bias.float())
                keep = same_camera[..., None]
                d6 = torch.where(keep, 0.0, pose[..., :6]) + x.new_tensor(_IDENTITY_6D)
                rotation = rotation_from_6d(d6)
                translation = torch.where(keep, 0.0, pose[..., 6:])
                raw["points"] = (rotation @ raw["points"][..., None])[..., 0] + translation
                raw["motion"] = (rotation @ raw["motion"][..., None])[..., 0]
                raw["normals"] = (rotation @ raw["normals"][..., None])[..., 0]
                raw["relative_rotation"], raw["relative_translation"] = rotation, translation
        logit = raw["visibility_logit"].squeeze(-1)
        conf = raw["confidence"].squeeze(-1)
        if self.confidence_activation == "softplus":
            confidence = F.softplus(conf) + 1e-6  # strictly positive: the loss takes log(c)
        else:
            confidence = 1.0 + torch.exp(conf.clamp(max=80.0))  # clamp: exp overflow guard, not a range limit
        pose = {k: raw[k] for k in ("relative_rotation", "relative_translation") if k in raw}
        # Fresh tensors, not views (a linear layer on (B, N, dim) returns a view of its 2D result): FSDP2
        # hooks a root module's outputs for backward and warns that an in-place op on a view bypasses it.
        return pose | {
            "points": _fresh(raw["points"]),
            "uv": _fresh(raw["uv"]),
            "visibility": torch.sigmoid(logit),
            "visibility_logit": _fresh(logit),
            "motion": _fresh(raw["motion"]),
            "normals": F.normalize(raw["normals"], dim=-1, eps=1e-6),
            "confidence": confidence,
        }


class QueryDecoder(nn.Module):
    """Decode query tokens against a clip's scene tokens.

    Use ``kv = project_scene(tokens)`` once per clip, then ``forward(query_tokens, kv)`` for any number
    of query batches. ``tokens: (B or 1, M, encoder_dim)``, ``query_tokens: (B, N, decoder_dim)``.
    """

    def __init__(self, config: D4RTConfig):
        super().__init__()
        self.config = config
        self.blocks = nn.ModuleList(
            CrossAttentionBlock(config.decoder_dim, config.encoder_dim, config.decoder_heads,
                                config.decoder_mlp_dim, config.layer_norm_eps)
            for _ in range(config.decoder_depth)
        )
        self.heads = PredictionHeads(config.decoder_dim, config.layer_norm_eps, config.confidence_activation,
                                     config.relative_pose_head, config.points_activation)

    def project_scene(self, tokens: torch.Tensor) -> SceneKV:
        """Keys and values of every block: a list of ``decoder_depth`` pairs ``(B, heads, M, d)``."""
        return [block.attn.project_context(tokens) for block in self.blocks]

    def forward(self, query_tokens: torch.Tensor, scene_kv: SceneKV,
                same_camera: torch.Tensor | None = None, attention_block: int | None = None,
                frame: FrameRestriction | None = None) -> dict[str, torch.Tensor]:
        """``query_tokens: (B, N, decoder_dim)``, ``scene_kv`` from :meth:`project_scene`, ``same_camera:
        (B, N)`` bool (t_cam == t_src; needed with ``relative_pose_head``) -> dict of ``(B, N, ...)``
        outputs (see :class:`PredictionHeads`); with ``attention_block`` also ``attention_log_probs (B, N, M)``,
        the log attention weights of that block's first head over the M scene tokens (a training signal on
        where a query looks; the answers do not change). ``frame``: the queries' time steps when the config
        has ``target_frame_heads`` (:class:`FrameRestriction`; required then)."""
        if attention_block is not None and not 0 <= attention_block < len(self.blocks):
            raise UserError(f"attention_block must be 0-{len(self.blocks) - 1}, got {attention_block}")
        if self.config.target_frame_heads and frame is None:
            raise ValueError("target_frame_heads needs each query's time step (frame)")
        recompute = self.config.gradient_checkpointing and self.training
        x = query_tokens
        attention = None
        for index, (block, (keys, values)) in enumerate(zip(self.blocks, scene_kv, strict=True)):
            if index == attention_block:
                attention = block.attn.attention_log_probs(block.norm1(x), keys, frame=frame)
            x = run_block(block, x, keys, values, frame, recompute=recompute)
        out = self.heads(x, same_camera)
        if attention is not None:
            out["attention_log_probs"] = attention
        return out
