"""Where training numbers go: TensorBoard, a JSON-lines file and the progress bar (rank 0 only).

Every logged record is one line of ``<run>/metrics.jsonl`` (``{"step": ..., "loss/3d": ..., ...}``) and,
when the ``tensorboard`` package is installed, scalars in ``<run>/tensorboard/`` (``tensorboard --logdir
<run>/tensorboard``). The progress bar shows the step, the loss and the ETA.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from d4rt.progress import progress_bar, write_line


def read_metrics(run: str | Path) -> list[dict]:
    """Every record of ``<run>/metrics.jsonl``, in the order logged."""
    return [json.loads(line) for line in (Path(run) / "metrics.jsonl").read_text().splitlines() if line.strip()]


def training_seconds(records: list[dict], clips_per_step: int) -> float:
    """The time a run spent in optimiser steps (and data loading; validation and checkpoint writes excluded):
    over the logged windows, the clips of each window divided by its ``throughput/clips_per_s``."""
    total, previous = 0.0, 0
    for record in records:
        if "throughput/clips_per_s" in record:
            total += (record["step"] - previous) * clips_per_step / record["throughput/clips_per_s"]
            previous = record["step"]
    return total


class TrainLogger:
    """Logs scalars of one run. ``enabled=False`` (ranks other than 0) makes every method a no-op."""

    def __init__(self, directory: str | Path, enabled: bool, total_steps: int, start_step: int,
                 tensorboard: bool = True, progress: bool = True):
        self.enabled = enabled
        self.writer = None
        self.bar = None
        if not enabled:
            return
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        self.jsonl = open(directory / "metrics.jsonl", "a")
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:
                print("d4rt train: the tensorboard package is not installed; logging to metrics.jsonl only "
                      "(pip install tensorboard, or set run.tensorboard: false)")
            else:
                self.writer = SummaryWriter(str(directory / "tensorboard"), purge_step=start_step + 1)
        self.bar = progress_bar(total=total_steps, initial=start_step, desc="train", unit="step", dynamic_ncols=True,
                        disable=not progress)

    def log(self, step: int, scalars: dict[str, float]) -> None:
        """Record ``scalars`` at ``step`` (names like ``loss/3d``, ``lr``, ``throughput/clips_per_s``)."""
        if not self.enabled:
            return
        record = {"step": step, **{k: (v if math.isfinite(v) else str(v)) for k, v in scalars.items()}}
        self.jsonl.write(json.dumps(record) + "\n")
        self.jsonl.flush()
        if self.writer is not None:
            for name, value in scalars.items():
                self.writer.add_scalar(name, value, step)
        if "loss/total" in scalars and self.bar is not None:
            self.bar.set_postfix(loss=f"{scalars['loss/total']:.4f}", l3d=f"{scalars.get('loss/3d', math.nan):.4f}",
                                 refresh=False)

    def advance(self, steps: int = 1) -> None:
        if self.bar is not None:
            self.bar.update(steps)

    def message(self, text: str) -> None:
        """A line printed above the progress bar."""
        if self.enabled:
            write_line(text)

    def close(self) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.close()
        if self.writer is not None:
            self.writer.close()
        self.jsonl.close()
