"""``d4rt info``: a model's architecture and parameter counts, built on the meta device (no memory,
no weights, instant even for the 1B-parameter giant)."""

from __future__ import annotations

import argparse
import json

import torch

from d4rt.config import D4RTConfig
from d4rt.cli import COMMANDS


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "info", help=COMMANDS["info"],
        description="Show the architecture and parameter counts of a model preset or config file.")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--preset", choices=D4RTConfig.preset_names(), default="tiny",
                        help="model preset (default: tiny)")
    source.add_argument("--config", metavar="JSON", help="a config.json written by save_pretrained")
    parser.add_argument("--json", action="store_true", help="print the counts and config as JSON")
    parser.set_defaults(func=run)


def model_info(config: D4RTConfig) -> dict:
    """Parameter counts of ``D4RT(config)`` (built on the meta device) and the derived sizes."""
    from d4rt.model import D4RT

    with torch.device("meta"):
        model = D4RT(config)
    return {
        "config": config.to_dict(),
        "parameters": model.parameter_counts(),
        "tokens_per_clip": config.num_scene_tokens(config.max_frames),
    }


def _millions(n: int) -> str:
    return f"{n / 1e6:,.2f}M"


def run(args: argparse.Namespace) -> int:
    config = D4RTConfig.load(args.config) if args.config else D4RTConfig.preset(args.preset)
    info = model_info(config)
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    c, p = config, info["parameters"]
    lines = [
        f"D4RT model '{c.name}'",
        f"  input      {c.max_frames} frames x {c.image_size}x{c.image_size} px, tubelets "
        f"{c.tubelet_frames}x{c.patch_size}x{c.patch_size}"
        + (f" every {c.step_frames} frame(s)" if c.step_frames != c.tubelet_frames else "")
        + f" -> {info['tokens_per_clip']} scene tokens (incl. aspect token)",
        f"  encoder    width {c.encoder_dim}, depth {c.encoder_depth} (global attention every "
        f"{c.global_attention_every}), heads {c.encoder_heads}, MLP {c.encoder_mlp_dim}",
        f"  queries    {c.fourier_frequencies} Fourier frequencies (1..{c.fourier_max:g} cycles/image), "
        f"RGB patch {c.rgb_patch_size}x{c.rgb_patch_size} from {c.rgb_patch_source} frames",
        f"  decoder    width {c.decoder_dim}, depth {c.decoder_depth}, heads {c.decoder_heads}, MLP {c.decoder_mlp_dim}",
        "parameters",
        f"  encoder          {p['encoder']:>15,d}  ({_millions(p['encoder'])})",
        f"  decoder          {p['decoder']:>15,d}  ({_millions(p['decoder'])})",
        f"    query embedding {p['query_embedding']:>14,d}",
        f"    blocks          {p['decoder_blocks']:>14,d}",
        f"    heads           {p['heads']:>14,d}",
        f"  total            {p['total']:>15,d}  ({_millions(p['total'])})",
    ]
    print("\n".join(lines))
    return 0

