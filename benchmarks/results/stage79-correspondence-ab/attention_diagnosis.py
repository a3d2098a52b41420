"""Stage 79's diagnosis: where each decoder head looks, on held-out training samples (seed 14,000,000).

    python benchmarks/results/stage79-correspondence-ab/attention_diagnosis.py CHECKPOINT [CHECKPOINT ...]

Per checkpoint, block and head: the mean attention mass on t_tgt's time step and on the token holding the point's
true (u, v) at t_tgt (against the uniform shares), over queries with t_src != t_tgt whose point is visible and in
frame at t_tgt. For block 0's first head also the (u, v) its attention points at (the attention within t_tgt's time
step renormalised, times the token centres) against the truth, beside the model's uv head and "no motion", as the
median L1 error over the same queries.
"""
import sys

import numpy as np
import torch

sys.path.insert(0, "tools")
from loss_probe import held_out_samples  # noqa: E402

from d4rt.model import D4RT  # noqa: E402
from d4rt.model.layers import FrameRestriction  # noqa: E402
from d4rt.training.config import TrainConfig  # noqa: E402

torch.set_num_threads(1)
config = TrainConfig.load("configs/ship-tiny-cpu-stage79-correspondence-ab.yaml")
samples = held_out_samples(config, 16, 1024, seed=14_000_000)
for checkpoint in sys.argv[1:]:
    model = D4RT.from_pretrained(checkpoint)
    stats, errors = {}, {"attention": [], "uv_head": [], "no_motion": []}
    with torch.no_grad():
        for s in samples:
            video, q = s["video"][None], s["queries"][None]
            steps, rows, cols = -(-video.shape[1] // 2), video.shape[2] // 8, video.shape[3] // 8
            tokens = model.encode_tokens(video, s["aspect_ratio"][None])
            kv = model.decoder.project_scene(tokens)
            x = model.query_embedding(q, video, False)
            uv_head = model(video, q, s["aspect_ratio"][None])["uv"][0]
            step = q[0, :, 3].long() // 2
            uv = s["uv"]
            ok = (s["valid"].bool() & s["uv_valid"].bool() & ((uv >= 0) & (uv <= 1)).all(-1)
                  & (q[0, :, 2] != q[0, :, 3]) & (s["visibility"] > 0.5))
            col = (uv[:, 0] * cols).floor().clamp(0, cols - 1).long()
            row = (uv[:, 1] * rows).floor().clamp(0, rows - 1).long()
            cell = (step * rows + row) * cols + col
            m = steps * rows * cols
            token_step = torch.arange(m) // (rows * cols)
            centres = torch.stack([(torch.arange(m) % cols + 0.5) / cols, (torch.arange(m) // cols % rows + 0.5) / rows], -1)
            heads = model.config.target_frame_heads
            frame = FrameRestriction(step[None], rows * cols, heads) if heads else None
            for b, (block, (k, v)) in enumerate(zip(model.decoder.blocks, kv)):
                a = torch.stack([block.attn.attention_log_probs(block.norm1(x), k, h, frame)[0].exp()
                                 for h in range(block.attn.heads)])  # (heads, N, M + 1), as the block attends
                on_step = (a[:, :, :m] * (token_step[None, None] == step[None, :, None])).sum(-1)
                on_cell = a[:, torch.arange(len(cell)), cell]
                for h in range(a.shape[0]):
                    stats.setdefault((b, h), []).append([on_step[h][ok].mean().item(), on_cell[h][ok].mean().item(),
                                                         1 / steps, 1 / m])
                if b == 0:
                    within = a[0, :, :m] * (token_step[None] == step[:, None])
                    pointed = (within / within.sum(-1, keepdim=True)) @ centres
                    errors["attention"] += (pointed - uv).abs().sum(-1)[ok].tolist()
                    errors["uv_head"] += (uv_head - uv).abs().sum(-1)[ok].tolist()
                    errors["no_motion"] += (q[0, :, :2] - uv).abs().sum(-1)[ok].tolist()
                x = block(x, k, v, frame)
    print(checkpoint)
    for (b, h), rows_ in stats.items():
        on_step, on_cell, uniform_step, uniform_cell = np.mean(rows_, 0)
        print(f"  block {b} head {h}: on t_tgt's step {on_step:.3f} (uniform {uniform_step:.3f}), "
              f"on the true token {on_cell:.4f} (uniform {uniform_cell:.4f})")
    print("  median L1 (u, v) error, moved visible points: " + ", ".join(
        f"{k} {np.median(v):.4f}" for k, v in errors.items()) + f" ({len(errors['attention'])} queries)")
