"""The finished rows of an unfinished ``d4rt eval``, kept on disk so that a stopped evaluation resumes.

An evaluation can be long (the synthetic benchmark with an 8-block decoder takes about two hours on one CPU core),
and a stopped one should lose one sequence at most, not the run. Each finished (method, sequence) row is written to
``<out>.partial/`` as soon as it is scored; ``d4rt eval --resume`` reuses the rows of a run that is the same
(benchmark, data folder and, per method, its fingerprint: a checkpoint's weights, config and camera recipe) and
refuses in one line a folder written by another run. Rows are JSON (no pickles); floats round-trip exactly.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.harness import SequenceResult
from d4rt.evaluation.metrics.depth import DepthEvaluation

IDENTITY_FILE = "run.json"


def partial_folder(out: Path) -> Path:
    """Where the rows of the evaluation that will write ``out`` are kept until it is written."""
    return out.with_name(out.name + ".partial")


def checkpoint_fingerprint(checkpoint: str | Path, pose_pairs: str | None = None,
                           flip_average: bool | None = None) -> str:
    """sha256 over a checkpoint's weight and config files (a directory) or its one file, the camera recipe and the
    flip averaging asked for (None: the config's, already in its bytes)."""
    path = Path(checkpoint)
    files = sorted(f for f in path.iterdir() if f.name in ("model.safetensors", "config.json")) if path.is_dir() \
        else [path]
    # Rows written before flip averaging existed hashed "pose_pairs=..." alone: a run resumed with no flip asked
    # for still finds them.
    asked = f"pose_pairs={pose_pairs}" + ("" if flip_average is None else f" flip_average={flip_average}")
    digest = hashlib.sha256(asked.encode())
    for file in files:
        digest.update(file.name.encode())
        with open(file, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def _array(value: np.ndarray | None) -> dict | None:
    return None if value is None else {"dtype": str(value.dtype), "shape": list(value.shape),
                                       "values": value.astype(np.float64).ravel().tolist()}


def _from_array(value: dict | None) -> np.ndarray | None:
    if value is None:
        return None
    return np.asarray(value["values"], dtype=np.float64).astype(value["dtype"]).reshape(value["shape"])


def row_to_json(row: SequenceResult) -> dict:
    """Everything a row holds, the arrays the aggregate pools included."""
    return {
        "name": row.name, "metrics": row.metrics, "notes": row.notes, "frames": row.frames,
        "registered": row.registered, "depth": {k: v.as_dict() for k, v in row.depth.items()},
        "pose_errors": None if row.pose_errors is None else [_array(a) for a in row.pose_errors],
        "confidence_errors": _array(row.confidence_errors),
    }


def row_from_json(data: dict) -> SequenceResult:
    """The inverse of :func:`row_to_json`."""
    pose = data["pose_errors"]
    return SequenceResult(
        name=data["name"], metrics=data["metrics"], notes=data["notes"], frames=data["frames"],
        registered=data["registered"], depth={k: DepthEvaluation(**v) for k, v in data["depth"].items()},
        pose_errors=None if pose is None else tuple(_from_array(a) for a in pose),
        confidence_errors=_from_array(data["confidence_errors"]),
    )


class PartialResults:
    """The rows of one evaluation on disk (see the module docstring).

    folder: where rows go (``partial_folder(out)``). run: what makes rows reusable across runs, e.g.
    ``{"benchmark": ..., "data": ...}``. methods: each method's name -> fingerprint (a checkpoint's, or its name for
    a baseline). resume: reuse a matching folder's rows; without it an existing folder is cleared.
    """

    def __init__(self, folder: Path, run: dict, methods: dict[str, str], resume: bool):
        self.folder = Path(folder)
        self.reused = 0
        identity = self.folder / IDENTITY_FILE
        if resume and identity.is_file():
            try:
                stored = json.loads(identity.read_text())
                if not isinstance(stored, dict) or not isinstance(stored.get("methods"), dict):
                    raise ValueError("no run and methods in it")
            except ValueError as error:
                raise UserError(f"cannot read {identity}: {error}; remove {self.folder} or drop --resume") from None
            if stored.get("run") != run:
                raise UserError(f"{self.folder} holds rows of another evaluation ({stored.get('run')} vs {run}): "
                                f"remove it or drop --resume")
            changed = [m for m, f in methods.items() if stored["methods"].get(m, f) != f]
            if changed:
                raise UserError(f"{self.folder} holds rows of a different {', '.join(changed)} (its checkpoint or "
                                f"camera recipe changed): remove it or drop --resume")
            methods = {**stored["methods"], **methods}
        elif self.folder.exists():
            shutil.rmtree(self.folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        identity.write_text(json.dumps({"run": run, "methods": methods}, indent=1))

    def _path(self, method: str, sequence: str) -> Path:
        # Sequence names may hold "/" (subsets): the file is named by a hash, the names are kept inside.
        return self.folder / (hashlib.sha1(f"{method}\0{sequence}".encode()).hexdigest()[:20] + ".json")

    def get(self, method: str, sequence: str) -> SequenceResult | None:
        """The stored row of ``method`` on ``sequence``, or None."""
        path = self._path(method, sequence)
        if not path.is_file():
            return None
        data = json.loads(path.read_text())
        if (data["method"], data["row"]["name"]) != (method, sequence):
            raise UserError(f"{path} is not the row of {method} on {sequence}: remove {self.folder}")
        self.reused += 1
        return row_from_json(data["row"])

    def put(self, method: str, sequence: str, row: SequenceResult) -> None:
        """Store a finished row (written whole, then renamed: a kill leaves no half row)."""
        path = self._path(method, sequence)
        part = path.with_suffix(".part")
        part.write_text(json.dumps({"method": method, "row": row_to_json(row)}))
        part.replace(path)

    def finish(self) -> None:
        """The evaluation's JSON is written: the rows are no longer needed."""
        shutil.rmtree(self.folder, ignore_errors=True)
