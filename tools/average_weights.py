"""A weighted average of checkpoints of one architecture (a "model soup"), written as a new checkpoint.

    python tools/average_weights.py STAGE2_DIR STAGE4_DIR --weights 0.5 0.5 --out DIR

Averaging a fine-tuned model with the model it started from keeps much of what fine-tuning gained while
undoing part of its drift (Wortsman et al., "Robust fine-tuning of zero-shot models", 2022: WiSE-FT); it
costs no training. Every checkpoint must have the same config (the averaged model's) and the same
tensors; weights must be positive and are normalised to sum to 1. Writes ``config.json`` and
``model.safetensors`` (D4RT.from_pretrained reads them) and prints what it averaged.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from d4rt.errors import UserError
from d4rt.model.weights import CONFIG_NAME, WEIGHTS_NAME


def average(directories: list[Path], weights: list[float]) -> tuple[dict[str, torch.Tensor], str]:
    """(averaged tensors, the shared config.json text); float tensors averaged in float64 and stored in
    their own dtype, others (none in D4RT today) required equal."""
    if len(directories) != len(weights) or len(directories) < 2:
        raise UserError("give at least two checkpoints and one weight per checkpoint")
    if any(w <= 0 for w in weights):
        raise UserError(f"weights must be positive, got {weights}")
    total = sum(weights)
    configs = [(d / CONFIG_NAME).read_text() for d in directories]
    if any(json.loads(c) != json.loads(configs[0]) for c in configs):
        raise UserError("the checkpoints have different configs: only one architecture can be averaged")
    states = [load_file(str(d / WEIGHTS_NAME)) for d in directories]
    if any(s.keys() != states[0].keys() for s in states):
        raise UserError("the checkpoints hold different tensors")
    out = {}
    for key, first in states[0].items():
        if first.is_floating_point():
            mixed = sum(s[key].double() * (w / total) for s, w in zip(states, weights))
            out[key] = mixed.to(first.dtype).contiguous()
        else:
            if any(not torch.equal(s[key], first) for s in states):
                raise UserError(f"tensor {key} is not floating point and differs between checkpoints")
            out[key] = first
    return out, configs[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", type=Path, help="directories written by save_pretrained")
    parser.add_argument("--weights", nargs="+", type=float, required=True, help="one per checkpoint")
    parser.add_argument("--out", type=Path, required=True, help="directory to write")
    args = parser.parse_args()
    tensors, config = average(args.checkpoints, args.weights)
    args.out.mkdir(parents=True, exist_ok=True)
    save_file(tensors, str(args.out / WEIGHTS_NAME), metadata={"format": "pt"})
    (args.out / CONFIG_NAME).write_text(config)
    total = sum(args.weights)
    print("averaged " + " + ".join(f"{w / total:.3g} x {d}" for d, w in zip(args.checkpoints, args.weights))
          + f" -> {args.out}")


if __name__ == "__main__":
    main()
