import sys, numpy as np, torch
sys.path.insert(0, "/work/main/tools")
from loss_probe import held_out_samples
from d4rt.training.config import TrainConfig
from d4rt.model import D4RT
from d4rt.model.layers import split_heads
torch.set_num_threads(2)
cfg = TrainConfig.load("/work/main/configs/ship-tiny-cpu-stage67-dense-depth-ab.yaml")
model = D4RT.from_pretrained(sys.argv[1])
samples = held_out_samples(cfg, 8, 1024, seed=14_000_000)
stats = {}
with torch.no_grad():
    for s in samples:
        video, q = s["video"][None], s["queries"][None]
        t = video.shape[1]; g = video.shape[2] // 8; gw = video.shape[3] // 8
        tokens = model.encode_tokens(video, s["aspect_ratio"][None])
        kv = model.decoder.project_scene(tokens)
        x = model.query_embedding(q, video, False)
        tt = q[0, :, 3].long() // 2
        uv = s["uv"]; ok = s["valid"].bool() & s["uv_valid"].bool() & ((uv >= 0) & (uv <= 1)).all(-1) & (q[0, :, 2] != q[0, :, 3]) & (s["visibility"] > 0.5)
        col = (uv[:, 0] * gw).floor().clamp(0, gw - 1).long(); row = (uv[:, 1] * g).floor().clamp(0, g - 1).long()
        cell = tt * g * gw + row * gw + col
        for bi, (block, (k, v)) in enumerate(zip(model.decoder.blocks, kv)):
            qh = split_heads(block.attn.q(block.norm1(x)), block.attn.heads)
            a = torch.softmax(qh @ k.transpose(-1, -2) / qh.shape[-1] ** 0.5, -1)[0]  # (H, N, M)
            m = a.shape[-1] - 1
            steps = torch.arange(m) // (g * gw)
            for h in range(a.shape[0]):
                on_time = (a[h, :, :m] * (steps[None] == tt[:, None])).sum(-1)
                on_cell = a[h, torch.arange(len(cell)), cell]
                src_cell = (q[0, :, 2].long() // 2) * g * gw + (q[0, :, 1] * g).floor().clamp(0, g-1).long() * gw + (q[0, :, 0] * gw).floor().clamp(0, gw-1).long()
                on_src = a[h, torch.arange(len(cell)), src_cell]
                key = (bi, h)
                stats.setdefault(key, []).append([on_time[ok].mean().item(), on_cell[ok].mean().item(), on_src[ok].mean().item(), 1.0 / (t // 2), 1.0 / m, (src_cell == cell)[ok].float().mean().item()])
        x = block(x, k, v)
for key, v in stats.items():
    v = np.mean(v, 0)
    print(key, "mass on t_tgt step %.3f (uniform %.3f); on true cell %.4f; on source cell %.4f (uniform %.4f); src==tgt cell %.2f" % (v[0], v[3], v[1], v[2], v[4], v[5]))
