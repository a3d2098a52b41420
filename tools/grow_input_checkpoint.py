"""A checkpoint given a larger encoder input (``d4rt.model.grow.with_input_size``), written as a new one.

    python tools/grow_input_checkpoint.py CHECKPOINT_DIR --image-size 96 --out DIR

Train it on with ``model.init_from: DIR``, ``image_size: 96`` and ``fourier_max_frequency`` (printed) among
``model.overrides``, and ``data.dataset.size: [96, 96]``; the trainer refuses the checkpoint under any other input
size. Only the encoder's spatial position table changes (resized as the encoder resizes it at run time).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.grow import with_input_size


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a directory written by D4RT.save_pretrained")
    parser.add_argument("--image-size", type=int, required=True, help="new encoder input side in pixels")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:  # a missing or mismatched checkpoint, or a size the patches do not tile: one line, no traceback
        model = D4RT.from_pretrained(args.checkpoint)
        if args.image_size <= model.config.image_size:
            raise UserError(f"--image-size {args.image_size} does not grow the input ({model.config.image_size})")
        larger = with_input_size(model, args.image_size).eval()
    except UserError as error:
        parser.error(str(error))
    larger.save_pretrained(args.out)
    c = larger.config
    print(f"{args.checkpoint} ({model.config.image_size} px, {model.config.grid_size}^2 tubelets a frame) -> {args.out} "
          f"({c.image_size} px, {c.grid_size}^2 tubelets); train with model.overrides image_size: {c.image_size}, "
          f"fourier_max_frequency: {c.fourier_max_frequency}")


if __name__ == "__main__":
    main()
