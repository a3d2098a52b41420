"""Speed and memory of d4rt: ``d4rt bench`` (docs/performance.md says what each figure means).

    options   BenchOptions: what is measured on what; the random-weight model and the clip
    timing    synchronised wall-clock timing (best of N after warm-up), peak memory
    flops     analytic FLOP counts from the config; peak TFLOP/s of known GPUs (MFU)
    encoder   clips/s, tokens/s, TFLOP/s, MFU
    decoder   queries/s per chunk size, KV cache on/off, source-embedding sharing on/off
    pose      camera-pose FPS through Reconstruction.cameras; COLMAP on the same clip
    tracks    the paper's Tab. 3: most full-video tracks while holding 60/24/10/1 FPS
    dense     occupancy-grid dense tracking: queries vs naive, wall time
    runner    one run of every part -> a result dict
    report    the result as a table and as JSON
"""

from d4rt.speed.options import BenchOptions
from d4rt.speed.report import format_table, write_json
from d4rt.speed.runner import run_benchmark

__all__ = ["BenchOptions", "format_table", "run_benchmark", "write_json"]
