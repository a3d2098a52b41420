"""Score a per-clip power stretch of cached depth maps: z' = m (z / m)^gamma, m the clip's median prediction.

    python depth_stretch.py CACHE.npz

Why: the tiny model's depth range looks squeezed (far/near ratios too small), so a stretch fitted on held-out clips
might be a cheap test-time calibration. Prints, per gamma, the pooled AbsRel and delta<1.25 after the benchmark's
per-clip scale&shift alignment (d4rt.evaluation.metrics.depth) and the median clip AbsRel; then per clip the
log-log slope of truth on prediction and of prediction on truth.
"""
import sys

import numpy as np

from d4rt.evaluation.metrics.depth import aggregate_depth, evaluate_depth

cache = np.load(sys.argv[1])
names = sorted({key.split("/")[0] for key in cache.files})
for gamma in (0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.7, 2.0):
    rows = []
    for name in names:
        pred, true = cache[f"{name}/pred"].astype(np.float64), cache[f"{name}/true"].astype(np.float64)
        median = np.median(pred[pred > 0])
        rows.append(evaluate_depth(median * (np.maximum(pred, 1e-6) / median) ** gamma, true, "scale&shift"))
    pooled = aggregate_depth(rows)
    print(f"gamma {gamma}: AbsRel (s&s) {pooled['abs_rel']:.4f}  delta<1.25 {pooled['delta_1_25']:.4f}  "
          f"median clip AbsRel {np.median([r.abs_rel for r in rows]):.4f}")
for name in names:
    pred, true = cache[f"{name}/pred"].ravel(), cache[f"{name}/true"].ravel()
    ok = (pred > 0) & np.isfinite(true) & (true > 0)
    lp, lt = np.log(pred[ok]), np.log(true[ok])
    print(f"{name}: slope of log true on log pred {np.polyfit(lp, lt, 1)[0]:.2f}, of log pred on log true "
          f"{np.polyfit(lt, lp, 1)[0]:.2f}, correlation {np.corrcoef(lp, lt)[0, 1]:.2f}")
