import sys, numpy as np, torch
from dataclasses import replace
sys.path.insert(0, "/work/main/tools")
from occlusion_probe import in_frame, HELD_OUT_SEED
from d4rt.evaluation.synthetic_benchmark import clip_specs
from d4rt.model import D4RT
from d4rt.geometry.camera import project
torch.set_num_threads(1)
model = D4RT.from_pretrained(sys.argv[1])
specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()[::3][:3]]
for spec in specs:
    seq = spec.render(); tr = seq.tracks
    src = np.concatenate([tr.query_frames[:, None], tr.query_xy], 1)
    rec = model.reconstruct(seq.rgb)
    pred = rec.tracks(src, frame="camera")
    prob = pred.visibility.T; vis = tr.visible
    truly = in_frame(tr.points, seq.intrinsics, seq.image_size)
    h, w = seq.image_size
    xy, z = project(tr.points, seq.intrinsics[:, None])
    tuv = np.stack([(xy[..., 0] + .5) / w, (xy[..., 1] + .5) / h], -1)
    puv = pred.uv.transpose(1, 0, 2)
    pxy, pz = project(pred.points.transpose(1, 0, 2), rec.cameras().intrinsics[:, None])
    if "--proj" in sys.argv: puv = np.stack([(pxy[..., 0] + .5) / w, (pxy[..., 1] + .5) / h], -1)
    out = ~truly & (z > 0)
    occl = truly & ~vis
    def dist_out(uv):  # how far outside [0,1] (0 if inside)
        return np.maximum(np.maximum(-uv, uv - 1), 0).max(-1)
    print(spec.name, f"T={seq.rgb.shape[0]} windows={rec.windows}", f"out {out.mean():.3f} occl {occl.mean():.3f}",
          f"p(vis): visible {prob[vis].mean():.3f} occl {prob[occl].mean():.3f} out {prob[out].mean():.3f}",
          f"true dist_out median {np.median(dist_out(tuv[out])):.3f} pred dist_out median {np.nanmedian(dist_out(puv[out])):.3f}",
          f"uv err visible {np.nanmedian(np.linalg.norm(puv[vis]-tuv[vis],axis=-1)):.3f} out {np.nanmedian(np.linalg.norm(puv[out]-tuv[out],axis=-1)):.3f}", flush=True)
    # per-frame offset from query frame
    qf = tr.query_frames
    gap = np.abs(np.arange(seq.rgb.shape[0])[:, None] - qf[None])
    for g in (1, 3, 7, 12, 20):
        m = gap == g
        if m.any():
            print(f"   gap {g}: true out {out[m].mean():.3f} uv err {np.nanmedian(np.linalg.norm(puv[m]-tuv[m],axis=-1)):.3f} true disp {np.nanmedian(np.linalg.norm(tuv[m]-np.broadcast_to(tr.query_xy/[w,h],tuv.shape)[m],axis=-1)):.3f} pred disp {np.nanmedian(np.linalg.norm(puv[m]-np.broadcast_to((tr.query_xy+.5)/[w,h],tuv.shape)[m],axis=-1)):.3f}")
