"""A checkpoint given a larger encoder input or shorter or overlapping tubelets (``d4rt.model.grow``), written anew.

    python tools/grow_input_checkpoint.py CHECKPOINT_DIR --image-size 96 --out DIR
    python tools/grow_input_checkpoint.py CHECKPOINT_DIR --tubelet-frames 1 --out DIR
    python tools/grow_input_checkpoint.py CHECKPOINT_DIR --tubelet-stride 1 --out DIR

Train it on with ``model.init_from: DIR`` and the changed fields (printed) among ``model.overrides``, with
``data.dataset.size: [96, 96]`` for a larger input; the trainer refuses the checkpoint under any other config. A
larger input changes only the encoder's spatial position table (resized as the encoder resizes it at run time);
shorter tubelets change the patch embedding (summed over the frames a tubelet no longer spans) and the time
position table (each old row repeated), so that a clip that does not move gives the old tokens once per frame;
overlapping tubelets keep the kernel (each old tubelet is still one of the new ones) and repeat the time rows.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.grow import with_input_size, with_tubelet_frames, with_tubelet_stride


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a directory written by D4RT.save_pretrained")
    parser.add_argument("--image-size", type=int, default=None, help="new encoder input side in pixels")
    parser.add_argument("--tubelet-frames", type=int, default=None, help="new frames per tubelet (a divisor of the "
                        "current span)")
    parser.add_argument("--tubelet-stride", type=int, default=None, help="new frames between tubelet starts (fewer "
                        "than now: overlapping tubelets)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    if sum(x is not None for x in (args.image_size, args.tubelet_frames, args.tubelet_stride)) != 1:
        parser.error("give one of --image-size, --tubelet-frames and --tubelet-stride")
    try:  # a missing or mismatched checkpoint, or a size the patches do not tile: one line, no traceback
        model = D4RT.from_pretrained(args.checkpoint)
        if args.tubelet_frames is not None:
            grown = with_tubelet_frames(model, args.tubelet_frames).eval()
        elif args.tubelet_stride is not None:
            grown = with_tubelet_stride(model, args.tubelet_stride).eval()
        elif args.image_size <= model.config.image_size:
            raise UserError(f"--image-size {args.image_size} does not grow the input ({model.config.image_size})")
        else:
            grown = with_input_size(model, args.image_size).eval()
    except UserError as error:
        parser.error(str(error))
    grown.save_pretrained(args.out)
    c, old = grown.config, model.config
    if args.tubelet_stride is not None:
        print(f"{args.checkpoint} (a tubelet every {old.step_frames} frames) -> {args.out} (every {c.step_frames}); "
              f"train with model.overrides tubelet_stride: {c.tubelet_stride}")
    elif args.tubelet_frames is not None:
        print(f"{args.checkpoint} ({old.tubelet_frames}-frame tubelets) -> {args.out} ({c.tubelet_frames}-frame "
              f"tubelets); train with model.overrides tubelet_frames: {c.tubelet_frames}")
    else:
        print(f"{args.checkpoint} ({old.image_size} px, {old.grid_size}^2 tubelets a frame) -> {args.out} "
              f"({c.image_size} px, {c.grid_size}^2 tubelets); train with model.overrides image_size: {c.image_size}, "
              f"fourier_max_frequency: {c.fourier_max_frequency}")


if __name__ == "__main__":
    main()
