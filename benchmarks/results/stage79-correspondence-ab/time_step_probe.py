import sys, numpy as np, torch
sys.path.insert(0, "tools")
from loss_probe import held_out_samples
from d4rt.model import D4RT
from d4rt.training.config import TrainConfig
torch.set_num_threads(1)
config = TrainConfig.load("configs/ship-tiny-cpu-stage79-correspondence-ab.yaml")
samples = [s for s in held_out_samples(config, 40, 16, seed=14_000_000)]
for ck in sys.argv[1:]:
    model = D4RT.from_pretrained(ck)
    feats, steps, nsteps = [], [], []
    with torch.no_grad():
        for s in samples:
            v = s["video"][None]
            tok = model.encode_tokens(v, s["aspect_ratio"][None])[0, :-1]
            k = model.decoder.project_scene(tok[None])[0][0][0]  # block 0 keys (heads, M, d)
            st = -(-v.shape[1] // 2)
            feats.append(tok.numpy()); steps.append(np.repeat(np.arange(st), tok.shape[0] // st)); nsteps.append(st)
    # regress step / (steps - 1) (relative time) and the absolute step, train on first 30 clips, test on the rest
    X = np.concatenate(feats); y = np.concatenate(steps).astype(float)
    split = sum(len(f) for f in feats[:30])
    Xa = np.c_[X, np.ones(len(X))]
    w = np.linalg.solve(Xa[:split].T @ Xa[:split] + 1e-1 * np.eye(Xa.shape[1]), Xa[:split].T @ y[:split])
    pred = Xa[split:] @ w
    print(ck, "absolute time step from scene tokens: R2 %.3f, mean abs err %.2f steps (std of y %.2f)" % (
        1 - np.mean((pred - y[split:]) ** 2) / np.var(y[split:]), np.mean(np.abs(pred - y[split:])), np.std(y[split:])))
