"""Figures people would rather look at than read: the camera trajectory (top and side views) and a
frame's depth beside its confidence and, where the truth is known, its error. Written as PNG with
matplotlib (``pip install 'd4rt[viewer]'``); :func:`plots_available` says whether it is installed.

Axes are d4rt's world (camera 0, OpenCV: x right, y down, z forward): the top view is x against z, the
side view z against height (-y).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plots_available() -> bool:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only: no display needed
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path: str | Path) -> Path:
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def trajectory_figure(path: str | Path, cam_to_world: np.ndarray, reference: np.ndarray | None = None,
                      title: str = "camera trajectory") -> Path:
    """Camera centres of ``cam_to_world (T, 4, 4)`` from above and from the side, with ``reference``
    (T, 4, 4), e.g. the ground truth already aligned to them, dashed beside; start and end marked."""
    plt = _pyplot()
    centres = cam_to_world[:, :3, 3]
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.2))
    views = (("top view", 0, 2, "x (right)", "z (forward)", 1), ("side view", 2, 1, "z (forward)", "height (-y)", -1))
    for ax, (name, a, b, xlabel, ylabel, sign) in zip(axes, views):
        if reference is not None:
            ref = reference[:, :3, 3]
            ax.plot(ref[:, a], sign * ref[:, b], "--", color="0.45", lw=1.5, label="ground truth")
        ax.plot(centres[:, a], sign * centres[:, b], "-", color="tab:blue", lw=2, label="d4rt")
        ax.scatter(centres[:1, a], sign * centres[:1, b], color="tab:green", zorder=3, label="first frame")
        ax.scatter(centres[-1:, a], sign * centres[-1:, b], color="tab:red", zorder=3, label="last frame")
        ax.set(title=name, xlabel=xlabel, ylabel=ylabel)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    fig.suptitle(title)
    return _save(plt, fig, path)


def depth_figure(path: str | Path, rgb: np.ndarray, depth: np.ndarray, confidence: np.ndarray,
                 true_depth: np.ndarray | None = None, title: str = "") -> Path:
    """One frame: ``rgb (H, W, 3)`` uint8, ``depth`` and ``confidence (h, w)``, and where ``true_depth (h, w)``
    is given (depth already in its scale), the relative error |depth - true| / true."""
    plt = _pyplot()
    panels = 4 if true_depth is not None else 3
    fig, axes = plt.subplots(1, panels, figsize=(3.4 * panels, 3.2))
    axes[0].imshow(rgb)
    axes[0].set_title("frame")
    valid = np.isfinite(depth) & (depth > 0)
    low, high = np.percentile(depth[valid], [2, 98]) if valid.any() else (0.0, 1.0)
    shown = axes[1].imshow(np.where(valid, depth, np.nan), cmap="turbo", vmin=low, vmax=high)
    fig.colorbar(shown, ax=axes[1], fraction=0.046, pad=0.04)
    axes[1].set_title("depth")
    shown = axes[2].imshow(confidence, cmap="viridis")
    fig.colorbar(shown, ax=axes[2], fraction=0.046, pad=0.04)
    axes[2].set_title("confidence (higher: surer)")
    if true_depth is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            error = np.abs(depth - true_depth) / true_depth
        shown = axes[3].imshow(error, cmap="magma", vmin=0, vmax=0.5)
        fig.colorbar(shown, ax=axes[3], fraction=0.046, pad=0.04)
        axes[3].set_title(f"relative error (mean {np.nanmean(error):.2f})")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title)
    return _save(plt, fig, path)


def evaluation_figure(path: str | Path, confidence_errors: dict[str, np.ndarray], abs_rel: dict[str, list[float]],
                      sequences: list[str], alignment: str, bins: int = 10) -> Path:
    """``d4rt eval``'s figure: left, each method's mean relative depth error by confidence decile (pixels of
    every sequence pooled: a useful confidence falls from left to right); right, each method's AbsRel per
    sequence.

    confidence_errors: method -> (K, 2) [confidence, relative error] (methods without confidence left
    out); abs_rel: method -> one AbsRel per sequence (None where missing); sequences: their names.
    """
    plt = _pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [1, 1.6]})
    for name, samples in confidence_errors.items():
        if not len(samples):
            continue
        edges = np.quantile(samples[:, 0], np.linspace(0, 1, bins + 1))
        which = np.clip(np.searchsorted(edges, samples[:, 0], side="right") - 1, 0, bins - 1)
        means = [samples[which == b, 1].mean() if (which == b).any() else np.nan for b in range(bins)]
        left.plot(np.arange(1, bins + 1), means, "o-", label=name)
    left.set(title="depth error by confidence", xlabel=f"confidence decile (1: least sure, {bins}: surest)",
             ylabel=f"mean |error| / true depth ({alignment})")
    left.grid(alpha=0.3)
    if confidence_errors:
        left.legend(fontsize=8)
    width = 0.8 / max(len(abs_rel), 1)
    x = np.arange(len(sequences))
    for i, (name, values) in enumerate(abs_rel.items()):
        right.bar(x + i * width, [np.nan if v is None else v for v in values], width, label=name)
    right.set(title=f"AbsRel per sequence ({alignment})", ylabel="AbsRel (lower is better)")
    right.set_xticks(x + width * (len(abs_rel) - 1) / 2, sequences, rotation=90, fontsize=6)
    right.legend(fontsize=8)
    right.grid(alpha=0.3, axis="y")
    return _save(plt, fig, path)
