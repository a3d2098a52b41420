"""A constant or log-linear correction of the estimated focal, fitted on the held-out focal clips, read on the
benchmark's focal clips (reported only; nothing is tuned on the benchmark).

    python focal_constant.py HELD_OUT.json BENCHMARK.json

HELD_OUT / BENCHMARK: tools/measure_focal.py outputs of one checkpoint (held-out clips, synthetic-dynamic-v1).
"""
import json
import sys

import numpy as np


def clips(path):
    report = json.load(open(path))
    (key,) = [k for k in report if k.startswith("synthetic")]
    rows = report[key]["clips"]
    return (np.array([r["true_fx_median"] for r in rows]), np.array([r["estimated_fx_median"] for r in rows]),
            np.array([r["size"][1] for r in rows], dtype=float))


def errors(true, estimated):
    e = np.abs(estimated / true - 1)
    return f"median {np.median(e):.4f} mean {np.mean(e):.4f}"


(ht, he, hw), (bt, be, bw) = clips(sys.argv[1]), clips(sys.argv[2])
print("as estimated: held-out", errors(ht, he), "| benchmark", errors(bt, be))
k = float(np.exp(np.median(np.log(ht / he))))
print(f"constant k = {k:.4f} (median held-out log ratio): held-out", errors(ht, k * he), "| benchmark", errors(bt, k * be))
b, a = np.polyfit(np.log(he / hw), np.log(ht / hw), 1)  # the least-squares map from estimate to truth, per width


def fit(e, w):
    return np.exp(a + b * np.log(e / w)) * w


print(f"log-linear log(f/W) = {a:.3f} + {b:.3f} log(f_est/W): held-out", errors(ht, fit(he, hw)),
      "| benchmark", errors(bt, fit(be, bw)))
print(f"log-log slope of estimate on truth (held-out): {np.polyfit(np.log(ht / hw), np.log(he / hw), 1)[0]:.3f}")
