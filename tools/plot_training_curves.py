"""Training curves of a ``d4rt train`` run as one PNG: loss terms and validation metrics against steps.

    pip install -e ".[docs]"          # matplotlib (a documentation tool, never needed at run time)
    python tools/plot_training_curves.py docs/model-card/metrics-stage1.jsonl docs/model-card/metrics-stage2.jsonl \
        --out docs/model-card/training-curves.png

Reads ``metrics.jsonl`` files (one JSON object per logged step, docs/training.md "Logging and
validation"). Several files are successive stages of one model (a stage started with
``model.init_from`` the previous one's weights, so its steps count from 0 again): they are drawn end to
end on one step axis, each stage's steps offset by the steps before it, with a dashed line where a
stage begins.
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


def join_stages(stages: list[list[dict]]) -> tuple[list[dict], list[int]]:
    """Records of successive stages on one step axis -> (records, the first step of each later stage)."""
    joined, starts, offset = [], [], 0
    for index, records in enumerate(stages):
        if index:
            starts.append(offset)
        joined += [{**r, "step": r["step"] + offset} for r in records]
        offset += max((r["step"] for r in records), default=0)
    return joined, starts


def plot(records: list[dict], out: Path, smooth: int, title: str, stage_starts: list[int] = ()) -> None:
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
        for start in stage_starts:
            ax.axvline(start, color="0.4", ls="--", lw=0.8)
    fig.suptitle(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("metrics", type=Path, nargs="+", help="metrics.jsonl of a run (several: its stages, in order)")
    parser.add_argument("--out", type=Path, required=True, help="PNG file to write")
    parser.add_argument("--smooth", type=int, default=20, help="logged windows per running median")
    parser.add_argument("--title", default="d4rt training curves")
    args = parser.parse_args()
    stages = [[json.loads(line) for line in path.read_text().splitlines() if line.strip()] for path in args.metrics]
    records, starts = join_stages(stages)
    plot(records, args.out, args.smooth, args.title, starts)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
