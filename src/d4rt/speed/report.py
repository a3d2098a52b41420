"""The benchmark result as a text table (for people) and as JSON (for machines)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from d4rt.errors import UserError


def _num(value, digits: int = 3) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if abs(value) >= 1000:
        return f"{value:,.0f}"
    return f"{value:.{digits}g}"


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f}%"


def _mib(n: int) -> str:
    return f"{n / 2**20:,.0f} MiB"


def format_table(result: dict) -> str:
    """Every figure of a :func:`d4rt.speed.runner.run_benchmark` result, one per line, by part."""
    e, d, p, dn = result["encoder"], result["decoder"], result["pose"], result["dense"]
    lines = [
        f"d4rt bench  preset {result['preset']}  {result['frames']} frames {result['height']}x{result['width']}"
        f" (encoder {result['encoder_input']}x{result['encoder_input']}, {e['scene_tokens']:,} scene tokens)"
        f"  {result['dtype']}  {result['device']} ({result['device_name']}, {result['threads']} threads)",
        f"torch {result['torch_version']}  compile {result['compile']}  video {result['video']}"
        "  RANDOM WEIGHTS (speed does not depend on them)",
        "",
        "encoder",
        f"  clips/s {_num(e['clips_per_s'])}   tokens/s {_num(e['tokens_per_s'])}   "
        f"{_num(e['flops'] / 1e9)} GFLOP/clip   {_num(e['tflops_per_s'])} TFLOP/s   "
        f"MFU {_percent(e['mfu'])}",
        f"  encode incl. resize {e['encode_s'] * 1e3:.1f} ms   scene keys/values (all decoder layers) "
        f"{e['scene_kv_s'] * 1e3:.1f} ms",
        "",
        f"decoder ({result['decoder']['track_queries']:,} track queries, "
        f"{_num(d['flops_per_query'] / 1e6)} MFLOP/query)",
        "  chunk      cached q/s    uncached q/s   cache speed-up",
    ]
    for row in d["chunks"]:
        tags = " ".join(t for t, on in (("default", row["default"]), ("auto", row["auto"])) if on)
        lines.append(f"  {row['chunk_size']:>6}  {row['cached_queries_per_s']:>13,.0f}  {row['uncached_queries_per_s']:>14,.0f}"
                     f"   {row['kv_cache_speedup']:>6.2f}x  {tags}")
    lines += [
        f"  3D tracks, source embedding shared {d['track_shared_queries_per_s']:,.0f} q/s vs not "
        f"{d['track_unshared_queries_per_s']:,.0f} q/s: {d['track_sharing_speedup']:.2f}x",
        "",
        f"camera pose  {p['pose_frames']} frames in {p['pose_s'] * 1e3:.1f} ms: {_num(p['pose_fps'])} FPS (encoder included, "
        f"{p['pose_grid']}x{p['pose_grid']} grid)",
    ]
    if "colmap" in p:
        from d4rt.speed.colmap_comparison import describe

        lines += ["", *describe(p["colmap"])]
    lines += ["", "full-video 3D tracks while holding a target FPS (Tab. 3: encode + decode, wall <= T / FPS)"]
    for fps, r in result["tracks"].items():
        note = "" if r["bracketed"] else "  (lower bound: trials ran out before a failing count)"
        lines.append(f"  {fps:>4} FPS  {r['tracks']:>10,d} tracks  ({len(r['trials'])} trials){note}")
    lines += ["", f"dense tracking ({dn['benchmark']}, coverage from the exact oracle, model decodes the same queries)"]
    for row in dn["clips"]:
        lines.append(f"  {row['clip']} grid {row['grid'][0]}x{row['grid'][1]}x{row['frames']}: {row['queries']:,} "
                     f"queries vs naive {row['naive_queries']:,} ({row['reduction']:.1f}x fewer), "
                     f"{row['tracks']:,} tracks, {row['wall_s']:.2f} s with the model")
    by_part = ", ".join(f"{part} {_mib(b)}" for part, b in result["peak_memory_bytes_by_part"].items())
    colmap = result["pose"].get("colmap_peak_rss_bytes")
    scope = "per part" if result["peak_memory_reset_per_part"] else "the process's so far, not reset per part"
    lines += ["", f"peak memory {_mib(result['peak_memory_bytes'])}"
              f"{' (CPU peak RSS)' if result['device'] == 'cpu' else ' (CUDA max allocated)'}, {scope}: {by_part}"
              + (f"; process peak while COLMAP ran {_mib(colmap)} (CPU RSS, d4rt's model and clip included)"
                 if colmap is not None else ""),
              f"total {result['total_s']:.1f} s"]
    return "\n".join(lines)


def write_json(path: str | os.PathLike, result: dict) -> Path:
    """Write the result as JSON (atomically: a temporary file, then a rename)."""
    path = Path(path)
    if not path.parent.is_dir():
        raise UserError(f"cannot write {path}: folder {path.parent} does not exist")
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    tmp.replace(path)
    return path
