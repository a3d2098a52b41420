"""``d4rt eval``: score D4RT and baselines on a benchmark; markdown table to stdout, JSON to a file."""

from __future__ import annotations

import argparse
from pathlib import Path

from d4rt.cli import COMMANDS


def register(subparsers) -> None:
    from d4rt.evaluation.baselines import BASELINES
    from d4rt.evaluation.benchmarks import BENCHMARKS
    from d4rt.evaluation.readers import FORMATS
    from d4rt.config import POSE_PAIRS

    p = subparsers.add_parser(
        "eval", help=COMMANDS["eval"],
        description="Evaluate D4RT (--checkpoint) and baselines (--baseline) with the field's protocols. "
                    f"Benchmarks: {', '.join(BENCHMARKS)}. The synthetic benchmark is regenerated; the others "
                    "read your copy of the dataset (--data). --data alone evaluates every sequence of a folder. "
                    "Prints a markdown table (per-sequence rows and the aggregate) and writes JSON.")
    p.add_argument("--benchmark", choices=sorted(BENCHMARKS), help="a named benchmark")
    p.add_argument("--data", type=Path, help="dataset folder (required for real benchmarks)")
    p.add_argument("--format", choices=sorted(FORMATS), help="layout of --data without --benchmark (default: detected)")
    p.add_argument("--checkpoint", help="D4RT checkpoint directory (written by save_pretrained)")
    p.add_argument("--baseline", action="append", choices=BASELINES, default=None,
                   help="baseline to run beside it (repeatable; default with a checkpoint: oracle, "
                        "constant-depth where the benchmark scores depth, static-camera and constant-velocity "
                        "where it scores poses)")
    p.add_argument("-o", "--out", type=Path, help="JSON results file (default: ./d4rt-eval-<benchmark>.json)")
    p.add_argument("--limit", type=int, help="evaluate only the first N sequences")
    p.add_argument("--device", default="cpu", help="torch device for the model")
    p.add_argument("--resume", action="store_true",
                   help="reuse the rows a stopped run of the same evaluation left in OUT.partial/ (each finished "
                        "sequence is kept there until OUT is written)")
    p.add_argument("--pose-pairs", choices=POSE_PAIRS,
                   help="the model's camera recipe: each frame against the window's 'first' camera (the paper's) "
                        "or against the previous frame, chained ('adjacent'), or against frames i-1, i-2, i-4, ... solved "
                        "together ('graph'); default: the model's own choice "
                        "(its config's pose_pairs)")
    p.add_argument("--flip-average", action=argparse.BooleanOptionalAction, default=None,
                   help="answer every query on the video and on its left-right mirror and average the two (two encoder "
                        "passes, twice the queries); default: the model's own choice (its config's flip_average)")
    p.set_defaults(func=run)


def run(args) -> int:
    from d4rt.errors import UserError
    from d4rt.evaluation.baselines import make_baseline
    from d4rt.evaluation.benchmarks import folder_benchmark, get_benchmark
    from d4rt.evaluation.harness import run_benchmark
    from d4rt.evaluation.partial_results import PartialResults, checkpoint_fingerprint, partial_folder
    from d4rt.evaluation.predictions import d4rt_predictor
    from d4rt.evaluation.report import to_markdown, write_json

    if args.benchmark is None and args.data is None:
        raise UserError("choose what to evaluate on: --benchmark NAME and/or --data DIR")
    if args.benchmark is not None and args.format is not None:
        raise UserError("--format is for --data without --benchmark (a benchmark knows its format)")
    benchmark = get_benchmark(args.benchmark) if args.benchmark else folder_benchmark(args.data, args.format)
    if args.data is not None and not benchmark.needs_data:
        raise UserError(f"{benchmark.name} is generated, not read: drop --data")
    benchmark.sequence_names(args.data)  # a missing or incomplete dataset is refused before any file is written
    baselines = args.baseline
    if baselines is None:
        if args.checkpoint is None:
            raise UserError("nothing to evaluate: pass --checkpoint and/or --baseline")
        baselines = (["oracle"] + (["constant-depth"] if "depth" in benchmark.tasks else [])
                     + (["static-camera", "constant-velocity"] if "pose" in benchmark.tasks else []))
    predictors = ([d4rt_predictor(args.checkpoint, args.device, args.pose_pairs, args.flip_average)]
                  if args.checkpoint else [])
    predictors += [make_baseline(name) for name in dict.fromkeys(baselines)]
    out = args.out or Path(f"d4rt-eval-{benchmark.name.replace(':', '-').replace('/', '-')}.json")
    fingerprints = {p.name: p.name for p in predictors}
    if args.checkpoint:
        fingerprints[predictors[0].name] = checkpoint_fingerprint(args.checkpoint, args.pose_pairs, args.flip_average)
    store = PartialResults(partial_folder(out), {"benchmark": benchmark.name, "data": str(args.data)},
                           fingerprints, args.resume)
    results = run_benchmark(benchmark, predictors, args.data, args.limit, store=store)
    if args.resume:
        print(f"--resume: {store.reused} finished rows reused from {store.folder}")
    print(to_markdown(benchmark, results))
    print(f"wrote {write_json(out, benchmark, results)}")
    store.finish()
    if "depth" in benchmark.tasks and benchmark.depth_alignments:
        write_figure(out.with_suffix(".png"), benchmark, results)
    return 0


def write_figure(path, benchmark, results) -> None:
    """The depth figure beside the JSON (d4rt.viz.plots.evaluation_figure), when matplotlib is installed."""
    import numpy as np

    from d4rt.viz.plots import evaluation_figure, plots_available

    if not plots_available():
        print(f"figure skipped ({path.name}): it needs matplotlib, pip install 'd4rt[viewer]'")
        return
    align = benchmark.depth_alignments[0]
    confidence = {r.method: np.concatenate([row.confidence_errors for row in r.rows]) for r in results
                  if r.rows and all(row.confidence_errors is not None for row in r.rows)}
    abs_rel = {r.method: [row.metrics.get(f"abs_rel[{align}]") for row in r.rows] for r in results
               if any(row.metrics.get(f"abs_rel[{align}]") is not None for row in r.rows)}
    names = [row.name for row in results[0].rows]
    print(f"wrote {evaluation_figure(path, confidence, abs_rel, names, align)}")
