import sys, numpy as np, torch
from dataclasses import replace
sys.path.insert(0, "/work/main/tools")
from occlusion_probe import in_frame, HELD_OUT_SEED
from d4rt.evaluation.synthetic_benchmark import clip_specs
from d4rt.model import D4RT
torch.set_num_threads(1)
model = D4RT.from_pretrained("/work/main/src/d4rt/assets/d4rt-tiny")
specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()[::3][:16]]
rows = []
for spec in specs:
    seq = spec.render(); tr = seq.tracks
    src = np.concatenate([tr.query_frames[:, None], tr.query_xy], 1)
    rec = model.reconstruct(seq.rgb)
    pred = rec.tracks(src, frame="camera")
    prob = pred.visibility.T; vis = tr.visible
    k = rec.cameras().intrinsics
    pts = pred.points.transpose(1, 0, 2)
    h, w = seq.image_size
    res = {}
    for margin in (0.0, 0.05, 0.1):
        with np.errstate(all="ignore"):
            from d4rt.geometry.camera import project
            xy, z = project(pts, k[:, None])
        x, y = (xy[..., 0] + 0.5) / w, (xy[..., 1] + 0.5) / h
        inside = (z > 0) & (x >= -margin) & (x <= 1 + margin) & (y >= -margin) & (y <= 1 + margin)
        res[f"gate3d@{margin}"] = np.mean(((prob > 0.5) & inside) == vis)
    truly = in_frame(tr.points, seq.intrinsics, seq.image_size)
    res["oa"] = np.mean((prob > 0.5) == vis)
    res["oracle_gate"] = np.mean(((prob > 0.5) & truly) == vis)
    res["pred_out"] = 1 - np.mean(inside)
    res["true_out"] = 1 - np.mean(truly)
    rows.append(res); print(spec.name, {a: round(float(b), 4) for a, b in res.items()}, flush=True)
print("MEAN", {a: round(float(np.mean([r[a] for r in rows])), 4) for a in rows[0]})
