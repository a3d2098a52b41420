"""Stage 79: how well a ridge probe reads each scene token's tubelet time step from a checkpoint's scene tokens.

    python benchmarks/results/stage79-correspondence-ab/time_step_probe.py CHECKPOINT [CHECKPOINT ...]

40 held-out training samples (seed 14,000,000): fitted on the tokens of the first 30, scored on the other 10.
"""
import sys

import numpy as np
import torch

sys.path.insert(0, "tools")
from loss_probe import held_out_samples  # noqa: E402

from d4rt.model import D4RT  # noqa: E402
from d4rt.training.config import TrainConfig  # noqa: E402

torch.set_num_threads(1)
config = TrainConfig.load("configs/ship-tiny-cpu-stage79-correspondence-ab.yaml")
samples = held_out_samples(config, 40, 16, seed=14_000_000)
for checkpoint in sys.argv[1:]:
    model = D4RT.from_pretrained(checkpoint)
    features, steps = [], []
    with torch.no_grad():
        for s in samples:
            video = s["video"][None]
            tokens = model.encode_tokens(video, s["aspect_ratio"][None])[0, :-1]  # the aspect-ratio token dropped
            count = -(-video.shape[1] // model.config.tubelet_frames)
            features.append(tokens.numpy())
            steps.append(np.repeat(np.arange(count), tokens.shape[0] // count))
    x = np.c_[np.concatenate(features), np.ones(sum(len(f) for f in features))]
    y = np.concatenate(steps).astype(float)
    split = sum(len(f) for f in features[:30])
    w = np.linalg.solve(x[:split].T @ x[:split] + 0.1 * np.eye(x.shape[1]), x[:split].T @ y[:split])
    error = x[split:] @ w - y[split:]
    print(f"{checkpoint}: time step from the scene tokens, held out: R^2 {1 - np.mean(error ** 2) / np.var(y[split:]):.3f}, "
          f"mean error {np.mean(np.abs(error)):.2f} steps (spread {np.std(y[split:]):.2f})")
