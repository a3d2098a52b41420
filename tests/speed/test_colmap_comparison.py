"""The COLMAP comparison of `d4rt bench --compare-colmap` is on equal terms: the same frames for both,
cold and warm times for both, accuracy beside time, and a COLMAP run that does not register every frame
is a failure with no speed-up."""

import numpy as np
import pytest

from d4rt.model import D4RT
from d4rt.speed.colmap_comparison import compare_with_colmap, describe
from d4rt.speed.options import BenchOptions


def test_a_colmap_run_that_loses_frames_is_a_failure_not_a_speedup():
    pytest.importorskip("pycolmap")
    options = BenchOptions(preset="tiny", frames=6, height=40, width=40, repeats=1, device="cpu",
                           compare_colmap=True).checked()
    result = compare_with_colmap(D4RT.from_pretrained(), options, trained=True)
    assert result["frames"] == 6 and result["size"] == [40, 40]
    assert 0 < result["d4rt_cold_s"] and 0 < result["d4rt_warm_s"] and np.isfinite(result["d4rt_ate"])
    assert set(result["colmap"]) == {"unknown_intrinsics", "known_intrinsics"}
    lines = "\n".join(describe(result))
    for run in result["colmap"].values():
        assert run["cold_s"] > 0 and run["warm_s"] > 0
        if run["registered_frames"] < 6:  # 40x40 frames give SIFT too little to register them all
            assert run["failed"] and run["speedup_warm"] is None and run["speedup_cold"] is None
            assert f"FAILED: registered {run['registered_frames']} of 6 frames, no speed-up" in lines
        else:
            assert not run["failed"] and run["speedup_warm"] == pytest.approx(run["warm_s"] / result["d4rt_warm_s"])
    untrained = compare_with_colmap(D4RT.from_pretrained(), options, trained=False)
    assert untrained["d4rt_ate"] is None and "n/a (random weights)" in describe(untrained)[1]
