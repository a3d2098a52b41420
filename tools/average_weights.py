"""A weighted average of checkpoints of one architecture (a "model soup"), written as a new checkpoint.

    python tools/average_weights.py STAGE2_DIR STAGE4_DIR --weights 0.5 0.5 --out DIR

Averaging a fine-tuned model with the model it started from keeps much of what fine-tuning gained while
undoing part of its drift (Wortsman et al., "Robust fine-tuning of zero-shot models", 2022: WiSE-FT); it
costs no training. Every checkpoint must have the same config (the averaged model's) and the same
tensors, with two exceptions, the parts the trainer's ``init_from`` may add to a checkpoint: the relative-pose
head and the dense depth head (a training aid; stage 67). A model trained with such a part from one without it may
be averaged with it. The average then has the part, whose tensors come from the checkpoints that have it (their
weights renormalised among them); its config is that of the first checkpoint with the pose head (its
``pose_pairs`` too, which they must share unless ``--pose-pairs`` names the average's) with every added part that
any checkpoint has. The motion-mask threshold (``motion_threshold``, an inference setting measured per model) must
also be shared unless ``--motion-threshold`` names the average's. Weights must be positive
and are normalised to sum to 1. Writes ``config.json`` and ``model.safetensors`` (D4RT.from_pretrained reads them)
and prints what it averaged.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from safetensors.torch import save_file

from d4rt.config import POSE_PAIRS, D4RTConfig
from d4rt.errors import UserError
from d4rt.model.weights import ADDABLE_PARTS, CONFIG_NAME, WEIGHTS_NAME, read_checkpoint


def _shared_config(configs: list[D4RTConfig]) -> D4RTConfig:
    """The averaged model's config: the checkpoints' common config, or, when some add a part, the config of the
    first with the relative-pose head (else the first) with every part that any of them adds."""
    thresholds = sorted({c.motion_threshold for c in configs})
    if len(thresholds) > 1:  # said apart from an architecture mismatch: one flag settles it
        raise UserError(f"the checkpoints name different motion_threshold values {thresholds}: name the average's "
                        "with --motion-threshold")
    if all(c == configs[0] for c in configs):
        return configs[0]
    headed = [c for c in configs if c.relative_pose_head]
    # Without a pose head the camera pairing is not compared (it only names how that head's poses are chained).
    bare = [c.replace(relative_pose_head=False, dense_depth_head=False,
                      pose_pairs="first" if headed else c.pose_pairs) for c in configs]
    if any(c != bare[0] for c in bare):
        raise UserError("the checkpoints have different configs: only one architecture can be averaged")
    if any(c.pose_pairs != headed[0].pose_pairs for c in headed):
        raise UserError("the checkpoints with a relative-pose head name different pose_pairs: set one in their "
                        "config.json files")
    return (headed or configs)[0].replace(dense_depth_head=any(c.dense_depth_head for c in configs))


def average(directories: list[Path], weights: list[float], pose_pairs: str | None = None,
            motion_threshold: float | None = None) -> tuple[dict[str, torch.Tensor], str]:
    """(averaged tensors, the averaged model's config.json text); float tensors averaged in float64 and stored
    in their own dtype, others (none in D4RT today) required equal. ``pose_pairs``: the average's camera
    pairing, whatever the checkpoints name (a pairing is a choice made at inference: a judge with
    PAIRING=best picks one per model, so a shipped model may name another than the run it is averaged with).
    ``motion_threshold``: the average's motion-mask threshold, whatever the checkpoints name (a run from weights of
    an older config may carry the default where its start carries a measured one)."""
    if len(directories) != len(weights) or len(directories) < 2:
        raise UserError("give at least two checkpoints and one weight per checkpoint")
    if any(w <= 0 for w in weights):
        raise UserError(f"weights must be positive, got {weights}")
    configs, states = zip(*(read_checkpoint(d) for d in directories))
    if pose_pairs is not None:
        configs = [c.replace(pose_pairs=pose_pairs) for c in configs]
    if motion_threshold is not None:
        configs = [c.replace(motion_threshold=motion_threshold) for c in configs]
    config = _shared_config(list(configs))
    keys = sorted(set().union(*(s.keys() for s in states)))
    if any(not key.startswith(tuple(ADDABLE_PARTS.values())) for s in states for key in set(keys) - s.keys()):
        raise UserError("the checkpoints hold different tensors")
    out = {}
    for key in keys:
        holders = [(s[key], w) for s, w in zip(states, weights) if key in s]
        first, total = holders[0][0], sum(w for _, w in holders)
        if first.is_floating_point():
            mixed = sum(tensor.double() * (w / total) for tensor, w in holders)
            out[key] = mixed.to(first.dtype).contiguous()
        else:
            if any(not torch.equal(tensor, first) for tensor, _ in holders):
                raise UserError(f"tensor {key} is not floating point and differs between checkpoints")
            out[key] = first
    return out, config.to_json()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", type=Path, help="directories written by save_pretrained")
    parser.add_argument("--weights", nargs="+", type=float, required=True, help="one per checkpoint")
    parser.add_argument("--out", type=Path, required=True, help="directory to write")
    parser.add_argument("--pose-pairs", choices=POSE_PAIRS, default=None,
                        help="the average's camera pairing, whatever the checkpoints name (default: theirs, shared)")
    parser.add_argument("--motion-threshold", type=float, default=None, metavar="X",
                        help="the average's motion-mask threshold, whatever the checkpoints name (default: theirs, "
                             "shared)")
    args = parser.parse_args()
    try:
        tensors, config = average(args.checkpoints, args.weights, args.pose_pairs, args.motion_threshold)
    except UserError as error:
        parser.error(str(error))
    args.out.mkdir(parents=True, exist_ok=True)
    save_file(tensors, str(args.out / WEIGHTS_NAME), metadata={"format": "pt"})
    (args.out / CONFIG_NAME).write_text(config)
    total = sum(args.weights)
    print("averaged " + " + ".join(f"{w / total:.3g} x {d}" for d, w in zip(args.checkpoints, args.weights))
          + f" -> {args.out}")


if __name__ == "__main__":
    main()
