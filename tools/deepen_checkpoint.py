"""A checkpoint grown deeper without changing what it computes (``d4rt.model.grow.deepen``), written as a new one.

    python tools/deepen_checkpoint.py CHECKPOINT_DIR --encoder-depth 10 --decoder-depth 6 --out DIR

Train it on with ``model.init_from: DIR`` and the new depths among ``model.overrides`` (``encoder_depth: 10``,
``decoder_depth: 6``); the trainer refuses the checkpoint under any other depths. Prints the parameter counts and
the largest difference between the two models' answers on a random clip (0 up to float rounding).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.grow import deepen


def largest_difference(a: D4RT, b: D4RT, frames: int = 8, queries: int = 256) -> float:
    """The largest absolute difference between the two models' outputs on one random clip and random queries."""
    g = torch.Generator().manual_seed(0)
    size = a.config.image_size
    video = torch.rand(1, frames, size, size, 3, generator=g)
    q = torch.cat([torch.rand(1, queries, 2, generator=g),
                   torch.randint(0, frames, (1, queries, 3), generator=g).float()], dim=-1)
    with torch.no_grad():
        out_a, out_b = a(video, q, torch.ones(1)), b(video, q, torch.ones(1))
    return max(float((out_a[k] - out_b[k]).abs().max()) for k in out_a)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a directory written by D4RT.save_pretrained")
    parser.add_argument("--encoder-depth", type=int, default=None, help="new encoder depth (default: unchanged)")
    parser.add_argument("--decoder-depth", type=int, default=None, help="new decoder depth (default: unchanged)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the new blocks' initialisation")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:  # a missing or mismatched checkpoint, or depths that do not grow it: one line, no traceback
        model = D4RT.from_pretrained(args.checkpoint)
        grown = deepen(model, args.encoder_depth, args.decoder_depth, seed=args.seed).eval()
    except UserError as error:
        parser.error(str(error))
    grown.save_pretrained(args.out)
    count = lambda m: sum(p.numel() for p in m.parameters())  # noqa: E731
    print(f"{args.checkpoint} ({model.config.encoder_depth}/{model.config.decoder_depth} blocks, {count(model):,} "
          f"parameters) -> {args.out} ({grown.config.encoder_depth}/{grown.config.decoder_depth} blocks, "
          f"{count(grown):,} parameters); largest output difference {largest_difference(model, grown):.2e}")


if __name__ == "__main__":
    main()
