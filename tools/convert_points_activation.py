"""A checkpoint with a linear points head re-expressed under ``points_activation: exp`` (stage 77), written as a new one.

    python tools/convert_points_activation.py CHECKPOINT_DIR --config TRAIN_CONFIG --out DIR [--samples 48]

Why: the ``exp`` activation (``d4rt.model.decoder.exp_distance``) changes what the points head's numbers mean, so a
trained linear head cannot be loaded under it as it is. This tool keeps every other weight and refits the points
head alone: on held-out samples drawn as ``TRAIN_CONFIG`` draws its training samples (seed 13,000,000, a stream no
stage or probe draws), it records the head's input features and the old head's points p (camera t_src, before any
relative pose), and solves by least squares for the linear head whose ``exp_distance`` is closest to ``p / s`` in
the log-compressed space the loss compares in (``r = p / |p| * log1p(|p|)`` of ``p / s``). ``s``, the median over
samples of the old points' mean |z|, puts a typical point near unit length, where ``exp`` bends; the motion head
and the relative-pose translation are divided by ``s`` too, so that the model keeps one unit for all three (the
losses are invariant to that unit). A linear head cannot answer the logarithm of a linear head exactly: the tool
prints how close the refit comes (R^2 in the log space; the median relative error of the points it answers).

Train it on with ``model.init_from: DIR`` and ``points_activation: exp`` among ``model.overrides``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from loss_probe import held_out_samples  # noqa: E402

from d4rt.errors import UserError  # noqa: E402
from d4rt.model import D4RT  # noqa: E402
from d4rt.model.decoder import exp_distance  # noqa: E402
from d4rt.training.config import TrainConfig  # noqa: E402
from d4rt.training.data import model_inputs  # noqa: E402

FIT_SEED = 13_000_000


def log_distance(points: torch.Tensor) -> torch.Tensor:
    """The inverse of ``exp_distance``: ``p / |p| * log1p(|p|)`` over the last axis (..., 3)."""
    length = torch.linalg.vector_norm(points, dim=-1, keepdim=True)
    return points * torch.where(length > 0, torch.log1p(length) / length.clamp_min(1e-12), torch.ones_like(length))


@torch.no_grad()
def head_features(model: D4RT, samples: list[dict[str, torch.Tensor]]) -> tuple[torch.Tensor, torch.Tensor]:
    """The points head's input (after its LayerNorm) and the old head's points for every query of ``samples``:
    ``(features (Q, dim), points (Q, 3))``, the points in camera t_src (before any relative pose)."""
    heads = model.decoder.heads
    captured: list[torch.Tensor] = []
    hook = heads.register_forward_pre_hook(lambda module, args: captured.append(args[0].detach()))
    try:
        model.eval()
        for sample in samples:
            batch = {k: v[None] for k, v in sample.items()}
            model(batch["video"], batch["queries"], batch["aspect_ratio"], **model_inputs(model.config, batch))
    finally:
        hook.remove()
    x = torch.cat([c.reshape(-1, c.shape[-1]) for c in captured]).float()
    x = F.layer_norm(x, heads.norm.normalized_shape, heads.norm.weight.float(), heads.norm.bias.float(), heads.norm.eps)
    points = heads.heads["points"]
    return x, F.linear(x, points.weight.float(), points.bias.float())


def fit_linear(features: torch.Tensor, targets: torch.Tensor, ridge: float = 1e-4) -> tuple[torch.Tensor, torch.Tensor]:
    """Least-squares ``targets ~ features @ W.T + b`` with a small ridge on W: ``(W (out, dim), b (out,))``."""
    mean_x, mean_y = features.mean(0), targets.mean(0)
    xc, yc = (features - mean_x).double(), (targets - mean_y).double()
    gram = xc.T @ xc / len(xc)
    gram += ridge * gram.diagonal().mean() * torch.eye(len(gram), dtype=gram.dtype)
    weight = torch.linalg.solve(gram, xc.T @ yc / len(xc)).T.float()
    return weight, mean_y - weight @ mean_x


def convert(model: D4RT, samples: list[dict[str, torch.Tensor]]) -> tuple[D4RT, dict[str, float]]:
    """``model`` (points_activation linear) re-expressed under ``exp`` (module docstring): the new model and the
    fit's figures (``scale``, ``r2``, ``median_relative_error``, ``queries``)."""
    if model.config.points_activation != "linear":
        raise UserError(f"the checkpoint's points_activation is {model.config.points_activation!r}, not 'linear'")
    features, points = head_features(model, samples)
    scale = float(torch.stack([p.reshape(-1, 3)[:, 2].abs().mean() for p in points.split(
        [s["queries"].shape[0] for s in samples])]).median())
    target = log_distance(points / scale)
    weight, bias = fit_linear(features, target)
    refit = features @ weight.T + bias
    r2 = 1.0 - float(((refit - target) ** 2).sum() / ((target - target.mean(0)) ** 2).sum())
    answered = exp_distance(refit) * scale
    relative = (answered - points).norm(dim=-1) / points.norm(dim=-1).clamp_min(1e-6)

    converted = D4RT(dataclasses.replace(model.config, points_activation="exp"))
    state = model.state_dict()
    state["decoder.heads.heads.points.weight"], state["decoder.heads.heads.points.bias"] = weight, bias
    for name in ("decoder.heads.heads.motion.weight", "decoder.heads.heads.motion.bias"):
        state[name] = state[name] / scale
    if model.config.relative_pose_head:  # rows 6-8 are the translation, in the points' unit
        for name in ("decoder.heads.relative_pose.weight", "decoder.heads.relative_pose.bias"):
            value = state[name].clone()
            value[6:] = value[6:] / scale
            state[name] = value
    converted.load_state_dict(state, strict=True)
    return converted.eval(), {"scale": scale, "r2": r2, "median_relative_error": float(relative.median()),
                              "queries": len(points)}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a directory written by D4RT.save_pretrained")
    parser.add_argument("--config", required=True, help="the training config whose samples the head is refitted on")
    parser.add_argument("--samples", type=int, default=48)
    parser.add_argument("--queries", type=int, default=2048)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    if args.samples < 1 or args.queries < 1:
        parser.error("--samples and --queries must be at least 1")
    try:  # a missing or mismatched checkpoint or config: one line, no traceback
        config = TrainConfig.load(args.config)
        model = D4RT.from_pretrained(args.checkpoint)
        converted, fit = convert(model, held_out_samples(config, args.samples, args.queries, seed=FIT_SEED))
    except UserError as error:
        parser.error(str(error))
    converted.save_pretrained(args.out)
    print(f"{args.checkpoint} -> {args.out} (points_activation exp): unit {fit['scale']:.4g} of the old points, "
          f"R^2 {fit['r2']:.4f} in the log space over {fit['queries']:,} queries, median relative point error "
          f"{fit['median_relative_error']:.4f}")


if __name__ == "__main__":
    main()
