"""The training loss of checkpoints on held-out samples drawn exactly as a training config draws them (issue 14).

    python tools/loss_probe.py CHECKPOINT [CHECKPOINT ...] --config configs/ship-tiny-cpu-stage39.yaml [--set KEY=VALUE] \\
        --out probe.json [--samples 64] [--queries 2048]

Why: the held-out benchmark figures (depth, focal, camera probes) move by less than their clips' spread in a run of
one session (stage 38), so two recipes compared over tens of CPU-minutes cannot be told apart by them. The loss the
runs minimise, measured on the same held-out samples for every checkpoint and compared per sample (paired), is the
most sensitive statistic of how much a run has learnt of its own task. It does not replace the benchmark figures:
a lower loss is necessary for a better model, not proof of one.

The samples are ``config``'s training dataset (the same clip lengths, sizes, scene options, augmentation and query
sampler) with its seed replaced by 6,000,000 (a stream no training stage, probe or benchmark draws), its first
``--samples`` indices, each with ``--queries`` queries (the same for every checkpoint, whatever a run trained
with; with a config whose model cuts its RGB patches from the original-resolution frames the samples carry those
too, and each checkpoint cuts its patches where its own config says). Every checkpoint answers them in fp32 without
gradients; the terms are ``d4rt_loss``'s under the config's
loss settings (``3d`` is the paper's L3D), plus ``motion_terms``' (``2d_moved``, ``2d_still``, ``2d_slope``: does the
model find a pixel in another frame?) and ``query_kind_terms``' (L3D over each kind of query: where the error is).

Writes JSON: per checkpoint the mean of every term over the samples and the per-sample values; and for every
checkpoint after the first, per term, the paired difference against the first (``tools/compare_evals.py``'s
paired bootstrap over samples: mean difference, 95% interval, samples on which it is lower). Prints a table.

``--reference-from PROBE.json`` takes the reference (the first model) from an earlier probe's figures instead of its
weights, so an arm can be paired with a control whose run folder is gone. The earlier probe must have drawn the same
samples (seed, count, queries and its config's dataset section, loaded with its own overrides; else a one-line
error). Where the two loss sections differ, only the terms that do not depend on the loss settings are paired
(``LOSS_FREE_TERMS``: L3D, its kinds and the motion terms).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from compare_evals import paired_bootstrap  # noqa: E402

from d4rt.cli.train import parse_overrides  # noqa: E402
from d4rt.data import build_dataset  # noqa: E402
from d4rt.errors import UserError  # noqa: E402
from d4rt.model import D4RT  # noqa: E402
from d4rt.training.config import TrainConfig  # noqa: E402
from d4rt.training.data import model_inputs  # noqa: E402
from d4rt.training.losses import d4rt_loss, point_loss  # noqa: E402

HELD_OUT_SEED = 6_000_000
# The terms reported in the table (all terms are in the JSON).
HIGHER_IS_BETTER = ("2d_slope",)
# The terms whose value does not depend on the loss settings: the only ones paired with a --reference-from probe
# whose loss section differs.
LOSS_FREE_TERMS = ("3d", "2d_moved", "2d_still", "2d_slope", "3d_depth", "3d_other_camera", "3d_track",
                   "3d_track_other_camera", "3d_moving", "3d_static")
SHOWN = ("3d", "2d", "2d_moved", "2d_still", "2d_slope", "pose_rotation", "pose_translation", "confidence_mean",
         "correspondence")


def held_out_samples(config: TrainConfig, samples: int, queries: int, seed: int = HELD_OUT_SEED
                     ) -> list[dict[str, torch.Tensor]]:
    """The first ``samples`` samples of the config's dataset with ``seed`` (default the held-out seed) and
    ``queries`` queries each."""
    dataset_config = config.data.dataset
    sampler = dataclasses.replace(dataset_config.sampler, num_queries=queries)
    dataset = build_dataset(dataclasses.replace(dataset_config, seed=seed, sampler=sampler, render_device="cpu"),
                            patch_frames=config.model.build().patches_from_original)
    return [dataset[i] for i in tqdm(range(samples), desc="rendering held-out samples", leave=False)]


@torch.no_grad()
def sample_losses(model: D4RT, samples: list[dict[str, torch.Tensor]], config: TrainConfig) -> dict[str, list[float]]:
    """Every loss term per sample: term -> (S,) values."""
    model.eval()
    terms: dict[str, list[float]] = {}
    for sample in samples:
        batch = {k: v[None] for k, v in sample.items()}
        out = model(batch["video"], batch["queries"], batch["aspect_ratio"],
                    attention_block=config.loss.attention_block, **model_inputs(model.config, batch))
        terms_of_sample = (d4rt_loss(out, batch, config.loss)[1] | motion_terms(out["uv"][0], sample)
                           | query_kind_terms(out["points"][0], sample))
        for key, value in terms_of_sample.items():
            terms.setdefault(key, []).append(float(value))
    return terms


# The kinds of query by their times (t_src, t_tgt, t_cam): a depth query, the same point seen from another frame's
# camera (what the camera recipes ask), and a point followed to another time in that time's camera or in another.
QUERY_KINDS = {
    "3d_depth": lambda s, t, c: (s == t) & (t == c),
    "3d_other_camera": lambda s, t, c: (s == t) & (t != c),
    "3d_track": lambda s, t, c: (s != t) & (t == c),
    "3d_track_other_camera": lambda s, t, c: (s != t) & (t != c),
}


def query_kind_terms(points: torch.Tensor, sample: dict[str, torch.Tensor]) -> dict[str, float]:
    """L3D (``point_loss``, normalised over all the sample's valid queries as in training) averaged over each kind
    of query in ``QUERY_KINDS``, and over the queries whose point moves (``3d_moving``: true scene-flow motion
    non-zero) and those whose point does not (``3d_static``). points: ``(N, 3)``. NaN where a sample has none."""
    valid = sample["valid"].bool()
    per_query = point_loss(points[None].float(), sample["points"][None].float(), valid[None])[0]
    s, t, c = sample["queries"][:, 2], sample["queries"][:, 3], sample["queries"][:, 4]
    moving = sample["motion"].abs().sum(-1) > 0
    masks = {name: kind(s, t, c) for name, kind in QUERY_KINDS.items()} | {"3d_moving": moving, "3d_static": ~moving}
    return {name: float(per_query[mask & valid].mean()) if (mask & valid).any() else float("nan")
            for name, mask in masks.items()}


def motion_terms(uv: torch.Tensor, sample: dict[str, torch.Tensor]) -> dict[str, float]:
    """How far the model moves a pixel between frames, against how far it truly moves.

    uv: ``(N, 2)`` the model's (u, v) in frame t_tgt for ``sample``'s queries. Over the queries with t_tgt != t_src
    whose true (u, v) in frame t_tgt lies inside the image (the 2D term's far-outside targets dominate its mean):
    ``2d_moved`` the median L1 error of the model's (u, v); ``2d_still`` the same for answering the query's own
    (u, v) (no motion; it does not depend on the model); ``2d_slope`` the least-squares slope of the model's
    displacement (uv - query uv) on the true one (1: moves pixels as far as they move; 0: does not move them).
    NaN where a sample has no such query. Why: the 2D term's mean says little about whether the model finds a
    pixel in another frame (correspondence), which depth from parallax, 3D tracks and the camera all need.
    """
    queries, target = sample["queries"], sample["uv"]
    inside = ((target >= 0) & (target <= 1)).all(-1)
    chosen = sample["uv_valid"].bool() & sample["valid"].bool() & inside & (queries[:, 2] != queries[:, 3])
    if not chosen.any():
        return {"2d_moved": float("nan"), "2d_still": float("nan"), "2d_slope": float("nan")}
    start, true, predicted = queries[chosen, :2], target[chosen], uv[chosen]
    true_shift, shift = true - start, predicted - start
    return {
        "2d_moved": float((predicted - true).abs().sum(-1).median()),
        "2d_still": float(true_shift.abs().sum(-1).median()),
        "2d_slope": float((shift * true_shift).sum() / (true_shift * true_shift).sum().clamp_min(1e-12)),
    }


def earlier_reference(path: str, config: TrainConfig, samples: int, queries: int
                      ) -> tuple[str, dict, tuple[str, ...] | None]:
    """The reference model of an earlier probe JSON: ``(name, its figures, the terms to pair or None for all)``.

    Raises UserError when that probe drew other samples than ``config`` with ``samples`` and ``queries`` would."""
    try:
        earlier = json.loads(Path(path).read_text())
        name = earlier["reference"]
        figures = earlier["models"][name]
        earlier_config = TrainConfig.load(earlier["config"], parse_overrides(earlier["overrides"]))
    except (OSError, ValueError, KeyError) as error:
        raise UserError(f"--reference-from {path}: not a readable loss-probe JSON ({error})") from error
    asked = (HELD_OUT_SEED, samples, queries)
    if (earlier["seed"], earlier["samples"], earlier["queries"]) != asked:
        raise UserError(f"--reference-from {path} drew (seed, samples, queries) = "
                        f"{(earlier['seed'], earlier['samples'], earlier['queries'])}, this probe {asked}")
    mine, theirs = (dataclasses.replace(c.data.dataset, seed=0) for c in (config, earlier_config))
    patches = (c.model.build().patches_from_original for c in (config, earlier_config))
    if mine != theirs or len(set(patches)) > 1:
        raise UserError(f"--reference-from {path}: its config {earlier['config']} draws other samples (its "
                        "data.dataset section, or where its model cuts RGB patches, differs from this probe's)")
    return name, figures, None if config.loss == earlier_config.loss else LOSS_FREE_TERMS


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+", help="model directories (model.safetensors + config.json)")
    parser.add_argument("--config", required=True, help="the training config whose samples and loss are probed")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a field of --config, as d4rt train --set (e.g. loss.weight_correspondence=0.2)")
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--queries", type=int, default=2048)
    parser.add_argument("--out", required=True)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1: beside a training run)")
    parser.add_argument("--reference-from", metavar="PROBE.json",
                        help="take the reference (first model) from an earlier probe's figures (module docstring)")
    args = parser.parse_args(argv)
    if args.samples < 2 or args.queries < 1:
        parser.error("--samples must be at least 2 and --queries at least 1")
    torch.set_num_threads(args.threads)
    try:  # the config and every checkpoint load (strictly) before anything is rendered: a bad path fails at once
        config = TrainConfig.load(args.config, parse_overrides(args.set))
        config.validate()
        networks = {checkpoint: D4RT.from_pretrained(checkpoint) for checkpoint in args.checkpoints}
    except UserError as error:
        parser.error(str(error))
    if config.data.tracks is not None:
        parser.error(f"{args.config} trains on clips with tracks (data.tracks); this probe draws synthetic clips only")
    models, paired_terms = {}, None
    if args.reference_from:
        try:
            name, models[name], paired_terms = earlier_reference(args.reference_from, config, args.samples,
                                                                 args.queries)
        except UserError as error:
            parser.error(str(error))
        if name in args.checkpoints:
            parser.error(f"--reference-from {args.reference_from}: its reference {name} is also a checkpoint to probe")
        args.checkpoints = [name, *args.checkpoints]
    samples = held_out_samples(config, args.samples, args.queries)
    for checkpoint, network in tqdm(networks.items(), desc="checkpoints"):
        terms = sample_losses(network, samples, config)
        models[checkpoint] = {"mean": {k: float(np.nanmean(v)) for k, v in terms.items()}, "samples": terms}
    reference, *others = args.checkpoints
    paired = {}
    for checkpoint in others:
        paired[checkpoint] = {}
        for key, values in models[checkpoint]["samples"].items():
            if (key in models[reference]["samples"] and key != "confidence_mean"
                    and (paired_terms is None or key in paired_terms)):
                base, new = np.array(models[reference]["samples"][key]), np.array(values)
                both = ~(np.isnan(base) | np.isnan(new))  # a sample without moved queries has no 2d_* terms
                paired[checkpoint][key] = paired_bootstrap(base[both], new[both], np.ones(int(both.sum())),
                                                           lower_is_better=key not in HIGHER_IS_BETTER)
    result = {"config": args.config, "overrides": args.set, "seed": HELD_OUT_SEED, "samples": args.samples, "queries": args.queries,
              "reference": reference, "reference_from": args.reference_from, "models": models,
              "paired_against_reference": paired}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1))
    shown = [k for k in SHOWN if k in models[reference]["mean"]]
    print("| checkpoint | " + " | ".join(shown) + " | L3D against the first (95% interval), lower on |")
    print("|---" * (len(shown) + 2) + "|")
    for checkpoint in args.checkpoints:
        means = " | ".join(f"{models[checkpoint]['mean'][k]:.4f}" for k in shown)
        p = paired.get(checkpoint, {}).get("3d")
        versus = (f"{p['difference']:+.4f} [{p['low']:+.4f}, {p['high']:+.4f}], {p['new_better_on']}/{p['sequences']}"
                  if p else "reference")
        print(f"| {checkpoint} | {means} | {versus} |")


if __name__ == "__main__":
    main()
