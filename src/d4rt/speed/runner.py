"""One benchmark run: every part in turn on one model and clip, gathered into one result dict."""

from __future__ import annotations

import time

import torch

from d4rt.devices import cpu_name
from d4rt.speed.decoder import bench_decoder
from d4rt.speed.dense import bench_dense
from d4rt.speed.encoder import bench_encoder
from d4rt.speed.options import BenchOptions, make_model, make_video
from d4rt.speed.pose import bench_pose
from d4rt.speed.timing import measure_peak, peak_rss_bytes, reset_peak_memory
from d4rt.speed.tracks import bench_tracks_at_fps

PARTS = ("encoder", "decoder", "pose", "tracks", "dense")


def device_name(device: torch.device) -> str:
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return cpu_name()


def run_benchmark(options: BenchOptions, log=print) -> dict:
    """Run every part and return the result dict that ``d4rt bench --json`` writes (see docs/performance.md).

    ``log(line)`` reports each part as it starts.
    """
    options = options.checked()
    if options.threads is not None:
        torch.set_num_threads(options.threads)
    device = torch.device(options.device)
    name = device_name(device)
    cpu_peak_resets = reset_peak_memory(device)  # False: CPU peaks are the whole process's so far
    started = time.perf_counter()

    model = make_model(options)
    video = make_video(options)
    config = model.config
    log(f"d4rt bench: preset {options.preset}, {options.frames} frames of {options.height}x{options.width} "
        f"-> {config.image_size}x{config.image_size} encoder input, {options.dtype} on {name} "
        f"({torch.get_num_threads()} CPU threads); RANDOM WEIGHTS (speed does not depend on them)")

    # Each part's peak memory is its own (the peak is reset before each), and COLMAP's is kept apart.
    peaks, rss_peaks = {}, {}

    def part(name: str, fn):
        result, peaks[name] = measure_peak(device, fn)
        rss_peaks[name] = peak_rss_bytes()  # reset with the device's peak
        return result

    log("encoder ...")
    encoder = part("encoder", lambda: bench_encoder(model, video, options, name))

    with options.autocast():
        scene = model.encode(video)
    log("decoder ...")
    decoder = part("decoder", lambda: bench_decoder(model, scene, options))
    del scene
    log("camera pose ...")
    pose = part("pose", lambda: bench_pose(model, video, options))
    if options.compare_colmap:
        from d4rt.speed.colmap_comparison import compare_with_colmap
        from d4rt.model.weights import bundled_model_dir

        log("camera pose beside COLMAP (same clip; cold and warm; with and without known intrinsics) ...")
        trained = options.preset == "tiny" and (bundled_model_dir() / "model.safetensors").is_file()
        judged = type(model).from_pretrained(device=device) if trained else model
        pose["colmap"], pose["colmap_peak_rss_bytes"] = measure_peak(
            torch.device("cpu"), lambda: compare_with_colmap(judged, options, trained))
    log("tracks at target FPS (Tab. 3) ...")
    tracks = part("tracks", lambda: bench_tracks_at_fps(model, video, options, decoder["track_shared_queries_per_s"]))
    log("dense tracking ...")
    dense = part("dense", lambda: bench_dense(model, options))

    preset = type(config).preset(options.preset)
    return {
        "device": str(device),
        "device_name": name,
        "preset": options.preset,
        "dtype": options.dtype,
        "frames": options.frames,
        "height": options.height,
        "width": options.width,
        "encoder_input": config.image_size,
        "max_frames_raised_from": preset.max_frames if config.max_frames != preset.max_frames else None,
        "video": options.video,
        "random_weights": True,
        "compile": options.compile,
        "quick": options.quick,
        "torch_version": torch.__version__,
        "threads": torch.get_num_threads(),
        "repeats": options.repeats,
        # the fixed interface
        "encoder_tokens_per_s": encoder["tokens_per_s"],
        "decoder_queries_per_s": decoder["queries_per_s"],
        "kv_cache_speedup": decoder["kv_cache_speedup_256"],
        "pose_fps": pose["pose_fps"],
        "dense_query_reduction": dense["query_reduction"],
        "tracks_at_fps": {f"{fps:g}": result["tracks"] for fps, result in tracks.items()},
        "peak_memory_bytes": max(peaks.values()),
        # everything else
        "peak_memory_bytes_by_part": peaks,
        "peak_memory_reset_per_part": device.type == "cuda" or cpu_peak_resets,
        "peak_rss_bytes": max(rss_peaks.values()),
        "encoder_clips_per_s": encoder["clips_per_s"],
        "encoder_tflops_per_s": encoder["tflops_per_s"],
        "mfu": encoder["mfu"],
        "default_chunk_size": decoder["default_chunk_size"],
        "track_sharing_speedup": decoder["track_sharing_speedup"],
        "encoder": encoder,
        "decoder": decoder,
        "pose": pose,
        "tracks": {f"{fps:g}": result for fps, result in tracks.items()},
        "dense": dense,
        "total_s": time.perf_counter() - started,
    }
