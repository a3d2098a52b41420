"""``d4rt bench`` through the real console entry point: a tiny run emits valid JSON with every field and
sane values; bad input gives one line and exit status 2."""

import json
import math
import subprocess
import sys

import pytest

from d4rt.reconstruction.reconstruction import DEFAULT_GRID
from subprocess_budget import budget

REQUIRED = ("device", "preset", "frames", "height", "width", "encoder_tokens_per_s", "decoder_queries_per_s",
            "kv_cache_speedup", "pose_fps", "dense_query_reduction", "tracks_at_fps", "peak_memory_bytes")


def run_cli(*args, timeout=budget(600)):
    return subprocess.run([sys.executable, "-m", "d4rt", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def quick_result(tmp_path_factory):
    path = tmp_path_factory.mktemp("bench") / "bench.json"
    done = run_cli("bench", "--preset", "tiny", "--device", "cpu", "--quick", "--no-progress", "--json", path)
    assert done.returncode == 0, done.stderr
    return json.loads(path.read_text()), done.stdout


@pytest.mark.slow(seconds=47)
def test_quick_run_writes_every_field_with_sane_values(quick_result):
    result, stdout = quick_result
    for key in REQUIRED:
        assert key in result, key
    assert result["device"] == "cpu" and result["preset"] == "tiny"
    assert (result["frames"], result["height"], result["width"]) == (2, 32, 32)
    assert result["random_weights"] is True and result["mfu"] is None  # no MFU off the GPU
    for key in ("encoder_tokens_per_s", "decoder_queries_per_s", "kv_cache_speedup", "pose_fps",
                "peak_memory_bytes", "encoder_clips_per_s", "encoder_tflops_per_s", "track_sharing_speedup"):
        assert isinstance(result[key], (int, float)) and math.isfinite(result[key]) and result[key] > 0, key
    assert result["dense_query_reduction"] > 1
    parts = result["peak_memory_bytes_by_part"]
    assert sorted(parts) == sorted(["encoder", "decoder", "pose", "tracks", "dense"])
    assert result["peak_memory_bytes"] == max(parts.values()) and "peak memory" in stdout
    assert isinstance(result["peak_memory_reset_per_part"], bool)
    counts = result["tracks_at_fps"]
    assert sorted(counts) == sorted(["60", "24", "10", "1"])
    by_fps = [counts[k] for k in ("60", "24", "10", "1")]
    assert all(isinstance(c, int) and c >= 0 for c in by_fps)
    # More tracks at lower FPS. Only the 60x apart ends are compared: neighbouring targets (2.4x apart) can
    # swap on a busy machine, and timings are the benchmark's to report, not a test's to assert.
    assert by_fps[-1] > by_fps[0]
    sizes = [row["chunk_size"] for row in result["decoder"]["chunks"]]
    assert 256 in sizes and result["default_chunk_size"] in sizes
    assert "RANDOM WEIGHTS" in stdout and "Tab. 3" in stdout
    assert result["pose"]["pose_grid"] == DEFAULT_GRID and f"{DEFAULT_GRID}x{DEFAULT_GRID} grid" in stdout


@pytest.mark.parametrize("args, message", [
    (["--frames", "0"], "frames must be"),
    (["--device", "cuda:7"], "device"),
    (["--device", "tpu"], "device"),
    (["--size", "32", "--height", "32"], "--size"),
    (["--tolerance", "2"], "tolerance"),
    (["--pose-grid", "1"], "pose grid"),
    (["--json", "/nonexistent-dir/x.json"], "does not exist"),
])
def test_bad_input_is_one_line_and_status_2(args, message):
    done = run_cli("bench", "--quick", "--no-progress", *args)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("d4rt bench: error:") and message in lines[0], done.stderr
    assert "Traceback" not in done.stderr
