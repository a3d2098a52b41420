"""Is the field of view in the encoder's scene tokens? A linear probe on frozen weights (issue 14's focal question).

    python tools/fov_probe.py CHECKPOINT --out probe.json [--train-clips 480]

Since stage 55 the models' focal lengths (the paper's pinhole-median recipe over decoded 3D points) follow the true
focal with a slope of only 0.60-0.63 in log space, and neither a finer input, a deeper encoder nor more steps moved
it. This probe separates the two places the field of view can be lost:

- **the encoder**: ridge regression from each clip's pooled scene tokens (the mean and the standard deviation over
  the tokens of ``model.encode``) to log(fx / W), fitted on ``--train-clips`` clips drawn like synthetic-dynamic-v1's
  (its 48 clip definitions cycled, from seeds 12,000,000 + i that no benchmark, probe or training stream uses),
  the ridge strength chosen by 5-fold cross-validation on them, scored on the 48 held-out clips of
  ``tools/measure_focal.py --held-out`` (seeds 7,000,000 + index);
- **the decoder and recipe**: the model's own focal on the same 48 held-out clips
  (``model.reconstruct(video).cameras()``).

The same probe on a randomly initialised model of the same configuration is the control: what pooled random
features of the pixels already give. If the trained encoder's probe reads the field of view much better than the
recipe does, the information is there and the decoder does not pass it on; if not, the encoder does not have it.
Per clip the figures are the clip's median true fx and the median over its frames of the estimate; errors are
|fx / fx_true - 1|; the slope is the least-squares slope of log(fx_est / W) on log(fx_true / W).

Writes JSON and prints a summary.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from d4rt.errors import UserError
from d4rt.evaluation.synthetic_benchmark import clip_specs
from d4rt.model import D4RT

HELD_OUT_SEED = 7_000_000  # tools/measure_focal.py --held-out
PROBE_TRAIN_SEED = 12_000_000  # no benchmark, probe or training stream uses it
FOLDS = 5
ALPHAS = np.logspace(-3, 4, 15)


def pool(tokens: torch.Tensor) -> torch.Tensor:
    """``tokens: (M, D)`` -> ``(2 * D,)``: their mean and standard deviation, the probe's features."""
    return torch.cat([tokens.mean(0), tokens.std(0)])


def pooled_tokens(model: D4RT, rgb: np.ndarray) -> np.ndarray:
    """(2 * encoder_dim,) the pooled scene tokens of a clip of any size (``model.encode`` resizes it)."""
    return pool(model.encode(rgb).tokens[0].float()).numpy()


def log_focal(fx: np.ndarray, width: int) -> float:
    """log of the median fx over the frames, in image widths."""
    return float(np.log(np.median(fx) / width))


def collect(models: dict[str, D4RT], specs, recipe: D4RT | None, desc: str) -> dict:
    """Features of every model, the true log focal and (with ``recipe``) the recipe's log focal, per clip."""
    features = {name: [] for name in models}
    true, estimated = [], []
    for spec in tqdm(specs, desc=desc, unit="clip"):
        sequence = spec.render()
        for name, model in models.items():
            features[name].append(pooled_tokens(model, sequence.rgb))
        true.append(log_focal(sequence.intrinsics[:, 0, 0], spec.width))
        if recipe is not None:
            estimated.append(log_focal(recipe.reconstruct(sequence.rgb).cameras().intrinsics[:, 0, 0], spec.width))
    return {"features": {k: np.stack(v) for k, v in features.items()}, "true": np.array(true),
            "recipe": np.array(estimated) if recipe is not None else None}


def ridge_coefficients(x: np.ndarray, y: np.ndarray, alpha: float) -> tuple[np.ndarray, float]:
    """Ridge on standardised features with an unpenalised intercept, returned in the raw features' units:
    ``(D,)`` coefficients and the intercept, so that ``x @ coefficients + intercept`` predicts ``y``."""
    mean, scale = x.mean(0), x.std(0) + 1e-8
    z = (x - mean) / scale
    weights = np.linalg.solve(z.T @ z + alpha * len(z) * np.eye(z.shape[1]), z.T @ (y - y.mean())) / scale
    return weights, float(y.mean() - mean @ weights)


def ridge_fit(x: np.ndarray, y: np.ndarray, alpha: float):
    """Ridge (``ridge_coefficients``) as a predictor of new features."""
    weights, intercept = ridge_coefficients(x, y, alpha)
    return lambda new: new @ weights + intercept


def choose_alpha(x: np.ndarray, y: np.ndarray, seed: int = 0) -> tuple[float, list[float]]:
    """The ridge strength with the lowest 5-fold cross-validated squared error, and every alpha's error."""
    folds = np.random.default_rng(seed).permutation(len(y)) % FOLDS
    errors = []
    for alpha in ALPHAS:
        squared = [np.mean((ridge_fit(x[folds != k], y[folds != k], alpha)(x[folds == k]) - y[folds == k]) ** 2)
                   for k in range(FOLDS)]
        errors.append(float(np.mean(squared)))
    return float(ALPHAS[int(np.argmin(errors))]), errors


def scores(estimated: np.ndarray, true: np.ndarray) -> dict:
    """Median / mean relative focal error and the log-log slope, over clips."""
    errors = np.abs(np.exp(estimated - true) - 1.0)
    slope = float(np.polyfit(true, estimated, 1)[0])
    return {"median_focal_error": float(np.median(errors)), "mean_focal_error": float(np.mean(errors)),
            "slope": slope, "per_clip_error": errors.round(4).tolist()}


def summary_line(label: str, result: dict) -> str:
    """One printed line of ``scores``' figures."""
    return (f"{label:16s} median {100 * result['median_focal_error']:5.1f}%  mean {result['mean_focal_error']:.3f}  "
            f"slope {result['slope']:.2f}")


def check_clip_counts(parser: argparse.ArgumentParser, train_clips: int, test_clips: int, held_out: int) -> None:
    """One-line errors for clip counts the probe cannot use: cross-validation needs a clip in every fold."""
    if train_clips < FOLDS:
        parser.error(f"--train-clips must be at least {FOLDS} (one per cross-validation fold), got {train_clips}")
    if not 1 <= test_clips <= held_out:
        parser.error(f"--test-clips must be 1-{held_out}, got {test_clips}")


def load_model(parser: argparse.ArgumentParser, checkpoint: str) -> D4RT:
    """The checkpoint, loaded strictly, or a one-line error naming the problem."""
    try:
        return D4RT.from_pretrained(checkpoint)
    except UserError as error:
        parser.error(str(error))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", help="model directory")
    parser.add_argument("--out", type=Path, required=True, help="JSON file to write")
    parser.add_argument("--train-clips", type=int, default=480, help="clips the probe is fitted on")
    parser.add_argument("--test-clips", type=int, default=48, help="only the first N held-out clips (1-48)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    args = parser.parse_args()
    specs = clip_specs()
    check_clip_counts(parser, args.train_clips, args.test_clips, len(specs))
    torch.set_num_threads(args.threads)

    trained = load_model(parser, args.checkpoint).eval()
    torch.manual_seed(0)
    untrained = D4RT(trained.config).eval()
    models = {"trained": trained, "untrained": untrained}
    train_specs = [replace(specs[i % len(specs)], seed=PROBE_TRAIN_SEED + i) for i in range(args.train_clips)]
    test_specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in specs[:args.test_clips]]

    train = collect(models, train_specs, None, "probe train clips")
    test = collect(models, test_specs, trained, "held-out clips")

    report = {"checkpoint": str(args.checkpoint), "train_clips": len(train_specs), "test_clips": len(test_specs),
              "recipe": scores(test["recipe"], test["true"]),
              "constant": scores(np.full_like(test["true"], train["true"].mean()), test["true"])}
    for name in models:
        alpha, cv = choose_alpha(train["features"][name], train["true"])
        predictor = ridge_fit(train["features"][name], train["true"], alpha)
        report[f"probe_{name}"] = {"alpha": alpha, "cv_mse": cv, **scores(predictor(test["features"][name]),
                                                                          test["true"])}
    args.out.write_text(json.dumps(report, indent=1))
    for key in ("constant", "recipe", "probe_trained", "probe_untrained"):
        print(summary_line(key, report[key]))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
