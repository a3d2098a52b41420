"""How well can a tiny encoder read the field of view at all? The encoder fine-tuned on focal alone (issue 14).

    python tools/fov_ceiling.py CHECKPOINT --out ceiling.json [--train-clips 1200 --minutes 20]

``tools/fov_probe.py`` asks whether a trained encoder's pooled tokens hold the field of view (a frozen linear
probe). This asks the next question: is the 20% focal target within reach of the architecture at its input size
on these scenes? The checkpoint's encoder and a linear head on its pooled scene tokens (mean and standard
deviation over tokens, the probe's features; the head starts as the probe's ridge fit) are trained end to end for
``--minutes`` on one task only, log(fx / W) with an L1 loss, on ``--train-clips`` clips drawn like
synthetic-dynamic-v1's from the probe's seeds (12,000,000 + i), frames flipped left-right at random (a flip keeps
the focal length). Scored on the 48 held-out clips of ``tools/measure_focal.py --held-out``. If even this reads
the field of view no better than the D4RT recipe, more D4RT training at this size will not either; if it reads it
much better, the information is there and D4RT's training signal does not teach it.

Writes JSON and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from d4rt.evaluation.synthetic_benchmark import clip_specs
from d4rt.model import D4RT
from d4rt.model.inputs import encoder_frames

from fov_probe import (HELD_OUT_SEED, PROBE_TRAIN_SEED, check_clip_counts, choose_alpha, load_model, log_focal, pool,
                       ridge_coefficients, scores, summary_line)


def render_clips(specs, size: int, desc: str) -> list[tuple[torch.Tensor, float, float]]:
    """Per clip: encoder-resolution frames (T, size, size, 3) uint8, aspect ratio W / H, true log(fx / W)."""
    clips = []
    for spec in tqdm(specs, desc=desc, unit="clip"):
        sequence = spec.render()
        frames = encoder_frames(torch.from_numpy(sequence.rgb), size, torch.device("cpu"))
        clips.append(((frames * 255).round().to(torch.uint8), spec.width / spec.height,
                      log_focal(sequence.intrinsics[:, 0, 0], spec.width)))
    return clips


def pooled(model: D4RT, frames: torch.Tensor, aspect: float) -> torch.Tensor:
    """(2 * encoder_dim,) mean and standard deviation over the scene tokens, differentiable."""
    return pool(model.encode_tokens(frames[None].float() / 255, torch.tensor([aspect]))[0])


def predict(model: D4RT, head: nn.Linear, clips) -> np.ndarray:
    """(clips,) the head's log(fx / W) for each of ``render_clips``' clips."""
    with torch.no_grad():
        return np.array([head(pooled(model, f, a)).item() for f, a, _ in clips])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", help="model directory")
    parser.add_argument("--out", type=Path, required=True, help="JSON file to write")
    parser.add_argument("--train-clips", type=int, default=1200)
    parser.add_argument("--minutes", type=float, default=20.0, help="wall time of the fine-tuning")
    parser.add_argument("--batch", type=int, default=4, help="clips per optimiser step")
    parser.add_argument("--lr", type=float, default=1e-4, help="peak learning rate (the head's is 10x)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    specs = clip_specs()
    check_clip_counts(parser, args.train_clips, len(specs), len(specs))
    if args.minutes <= 0 or args.batch < 1:
        parser.error(f"--minutes must be positive and --batch at least 1, got {args.minutes} and {args.batch}")
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)

    model = load_model(parser, args.checkpoint)
    size = model.config.image_size
    train = render_clips([replace(specs[i % len(specs)], seed=PROBE_TRAIN_SEED + i) for i in range(args.train_clips)],
                         size, "train clips")
    test = render_clips([replace(s, seed=HELD_OUT_SEED + s.index) for s in specs], size, "held-out clips")
    train_true = np.array([t for _, _, t in train])
    test_true = np.array([t for _, _, t in test])

    # The head starts as the frozen probe: ridge on standardised features, folded into one linear layer.
    model.eval()
    with torch.no_grad():
        features = np.stack([pooled(model, f, a).numpy() for f, a, _ in tqdm(train, desc="probe features")])
    alpha, _ = choose_alpha(features, train_true)
    weights, intercept = ridge_coefficients(features, train_true, alpha)
    head = nn.Linear(features.shape[1], 1)
    with torch.no_grad():
        head.weight.copy_(torch.from_numpy(weights).float()[None])
        head.bias.fill_(intercept)
    report = {"checkpoint": str(args.checkpoint), "train_clips": len(train), "test_clips": len(test),
              "probe_alpha": alpha, "start": scores(predict(model, head, test), test_true)}

    model.train()
    optimiser = torch.optim.AdamW([{"params": model.encoder.parameters(), "lr": args.lr},
                                   {"params": head.parameters(), "lr": 10 * args.lr}], weight_decay=0.01)
    peaks = [g["lr"] for g in optimiser.param_groups]
    start, step, losses, curve = time.monotonic(), 0, [], []
    budget = args.minutes * 60
    while (elapsed := time.monotonic() - start) < budget:
        fraction = elapsed / budget
        for group, peak in zip(optimiser.param_groups, peaks):  # 30 warm-up steps, then cosine over the wall time
            group["lr"] = peak * min(1.0, (step + 1) / 30) * 0.5 * (1 + math.cos(math.pi * fraction))
        loss = 0.0
        for index in rng.integers(0, len(train), args.batch):
            frames, aspect, target = train[index]
            if rng.random() < 0.5:
                frames = frames.flip(2)
            loss = loss + (head(pooled(model, frames, aspect)) - target).abs().sum() / args.batch
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
        step += 1
        if step % 50 == 0:
            curve.append({"step": step, "seconds": round(elapsed), "train_l1": float(np.mean(losses[-50:]))})
            print(f"step {step} {elapsed:.0f} s train L1 {curve[-1]['train_l1']:.4f}", flush=True)
    model.eval()
    report.update(steps=step, curve=curve, end=scores(predict(model, head, test), test_true),
                  end_train=scores(predict(model, head, train[:200]), train_true[:200]))
    args.out.write_text(json.dumps(report, indent=1))
    for key in ("start", "end", "end_train"):
        print(summary_line(key, report[key]))
    print(f"{step} steps; wrote {args.out}")


if __name__ == "__main__":
    main()
