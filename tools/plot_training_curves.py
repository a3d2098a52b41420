"""Training curves of a ``d4rt train`` run as one PNG: loss terms and validation metrics against steps.

    pip install -e ".[docs]"          # matplotlib (a documentation tool, never needed at run time)
    python tools/plot_training_curves.py docs/model-card/metrics.jsonl --out docs/model-card/training-curves.png

Reads ``metrics.jsonl`` (one JSON object per logged step, docs/training.md "Logging and validation").
Training loss terms are noisy per window (one clip per step), so they are drawn faint as logged and
bold as a running median over ``--smooth`` logged windows; validation metrics are drawn as logged.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt
import numpy as np

LOSS_TERMS = ("3d", "2d", "visibility", "motion", "normal")
PANELS = (  # (title, [(metric key, label)], log scale)
    ("validation: loss terms", [(f"val/loss/{t}", t) for t in LOSS_TERMS], True),
    ("validation: video depth AbsRel", [("val/abs_rel_scale_shift", "scale & shift"), ("val/abs_rel_scale", "scale")],
     False),
    ("validation: camera ATE (Sim(3)-aligned)", [("val/ate", "ATE")], False),
    ("validation: 3D tracks (camera frame)", [("val/apd3d", "APD3D"), ("val/oa", "OA"), ("val/aj", "3D-AJ")], False),
)


def series(records: list[dict], key: str) -> tuple[np.ndarray, np.ndarray]:
    rows = [(r["step"], r[key]) for r in records if r.get(key) is not None]
    if not rows:
        return np.zeros(0), np.zeros(0)
    steps, values = np.array(rows, dtype=float).T
    return steps, values


def running_median(values: np.ndarray, window: int) -> np.ndarray:
    """Median of each value and the window - 1 before it (robust to the rare clip with a huge loss)."""
    return np.array([np.median(values[max(0, i + 1 - window): i + 1]) for i in range(len(values))])


def plot(records: list[dict], out: Path, smooth: int, title: str) -> None:
    fig, axes = plt.subplots(2, 3, figsize=(16, 8.5), constrained_layout=True)
    axes = axes.ravel()
    ax = axes[0]
    for term in LOSS_TERMS:
        steps, values = series(records, f"loss/{term}")
        line, = ax.plot(steps, running_median(values, smooth), label=term, lw=1.6)
        ax.plot(steps, values, color=line.get_color(), alpha=0.15, lw=0.6)
    ax.set(title=f"training: loss terms, unweighted\n(bold: running median of {smooth} windows)", yscale="log", xlabel="step")
    ax.legend(fontsize=8)
    ax = axes[1]
    steps, values = series(records, "loss/total")
    ax.plot(steps, values, color="0.7", lw=0.6)
    ax.plot(steps, running_median(values, smooth), color="k", lw=1.6, label="total (weighted)")
    ax.set(title="training: total loss and learning rate", xlabel="step")
    twin = ax.twinx()
    twin.plot(*series(records, "lr"), color="tab:red", lw=1.0, label="learning rate")
    twin.set_ylabel("learning rate", color="tab:red")
    ax.legend(fontsize=8, loc="upper right")
    for ax, (panel_title, keys, log) in zip(axes[2:], PANELS):
        for key, label in keys:
            steps, values = series(records, key)
            if len(steps):
                ax.plot(steps, values, marker="o", ms=3, label=label)
        ax.set(title=panel_title, xlabel="step", yscale="log" if log else "linear")
        ax.legend(fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("metrics", type=Path, help="metrics.jsonl of a run")
    parser.add_argument("--out", type=Path, required=True, help="PNG file to write")
    parser.add_argument("--smooth", type=int, default=20, help="logged windows per running median")
    parser.add_argument("--title", default="d4rt training curves")
    args = parser.parse_args()
    records = [json.loads(line) for line in args.metrics.read_text().splitlines() if line.strip()]
    plot(records, args.out, args.smooth, args.title)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
