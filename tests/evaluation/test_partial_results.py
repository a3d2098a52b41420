"""d4rt.evaluation.partial_results: a stored row comes back exactly; a folder of another run is refused."""

import json
import math

import numpy as np
import pytest

from d4rt.errors import UserError
from d4rt.evaluation.harness import SequenceResult
from d4rt.evaluation.metrics.depth import DepthEvaluation
from d4rt.evaluation.partial_results import PartialResults, row_from_json, row_to_json


def a_row() -> SequenceResult:
    rng = np.random.default_rng(0)
    return SequenceResult(
        name="subset/seq_01", metrics={"abs_rel[scale]": 0.1 / 3, "ate": None, "aj": float("nan")},
        notes=["3 of 8 frames registered"], depth={"scale": DepthEvaluation(1 / 3, 0.7, 1234, 2.5, 0.0)},
        pose_errors=(rng.random(28), rng.random(28).astype(np.float32)), frames=8, registered=3,
        confidence_errors=rng.random((50, 2)).astype(np.float32))


def test_a_row_round_trips_exactly_through_json():
    row = a_row()
    back = row_from_json(json.loads(json.dumps(row_to_json(row))))
    assert back.name == row.name and back.notes == row.notes and (back.frames, back.registered) == (8, 3)
    assert back.metrics["abs_rel[scale]"] == row.metrics["abs_rel[scale]"] and back.metrics["ate"] is None
    assert math.isnan(back.metrics["aj"]) and back.depth == row.depth
    for a, b in zip(row.pose_errors + (row.confidence_errors,), back.pose_errors + (back.confidence_errors,)):
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)


def test_rows_are_kept_per_method_and_another_run_is_refused(tmp_path):
    folder = tmp_path / "out.json.partial"
    run = {"benchmark": "sintel", "data": "/data"}
    store = PartialResults(folder, run, {"d4rt": "abc", "oracle": "oracle"}, resume=False)
    store.put("d4rt", "subset/seq_01", a_row())
    assert store.get("oracle", "subset/seq_01") is None and store.get("d4rt", "subset/seq_01").frames == 8
    again = PartialResults(folder, run, {"d4rt": "abc"}, resume=True)
    assert again.get("d4rt", "subset/seq_01") is not None and again.reused == 1
    with pytest.raises(UserError, match="rows of another evaluation"):
        PartialResults(folder, {**run, "benchmark": "bonn"}, {"d4rt": "abc"}, resume=True)
    with pytest.raises(UserError, match="rows of a different d4rt"):
        PartialResults(folder, run, {"d4rt": "xyz"}, resume=True)
    (folder / "run.json").write_text("[]")
    with pytest.raises(UserError, match="cannot read .*run.json"):
        PartialResults(folder, run, {"d4rt": "abc"}, resume=True)
    PartialResults(folder, run, {"d4rt": "xyz"}, resume=False)  # without --resume: cleared
    assert list(folder.glob("*.json")) == [folder / "run.json"]
