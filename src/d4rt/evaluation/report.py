"""Results as a markdown report (summary, then one per-sequence table per method) and as JSON."""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

from d4rt import __version__
from d4rt.evaluation.benchmarks import Benchmark
from d4rt.evaluation.harness import MethodResults, SequenceResult, metric_columns


def format_value(value: float | None) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    return f"{value:.4g}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def to_markdown(benchmark: Benchmark, results: list[MethodResults]) -> str:
    columns = metric_columns(benchmark)
    lines = [f"## d4rt eval: {benchmark.name}", "", benchmark.description + ".", ""]
    lines += _table(["method", *columns], [[r.method, *(format_value(r.aggregate[c]) for c in columns)]
                                           for r in results])
    for r in results:
        lines += ["", f"### {r.method}", ""]
        rows = [[row.name, *(format_value(row.metrics[c]) for c in columns)] for row in r.rows]
        rows.append(["**all**", *(format_value(r.aggregate[c]) for c in columns)])
        lines += _table(["sequence", *columns], rows)
        notes = [f"- {row.name}: {note}" for row in r.rows for note in row.notes]
        if notes:
            lines += ["", "Notes:", *notes]
    return "\n".join(lines) + "\n"


def to_json(benchmark: Benchmark, results: list[MethodResults]) -> dict:
    settings = asdict(benchmark)
    settings["read_options"] = {k: repr(v) for k, v in benchmark.read_options}
    return {
        "d4rt_version": __version__,
        "benchmark": settings,
        "columns": metric_columns(benchmark),
        "methods": [{"name": r.method, "aggregate": r.aggregate,
                     "sequences": [_sequence_json(row) for row in r.rows]}
                    for r in results],
    }


def _sequence_json(row: SequenceResult) -> dict:
    out = {"name": row.name, "metrics": row.metrics, "notes": row.notes}
    if row.valid_pixels is not None:  # its weight in the pooled depth figures (tools/compare_evals.py re-pools)
        out["valid_pixels"] = row.valid_pixels
    return out


def write_json(path: Path, benchmark: Benchmark, results: list[MethodResults]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_without_nan(to_json(benchmark, results)), indent=1, allow_nan=False))
    return path


def _without_nan(value):
    """NaN is not JSON: undefined metrics are written as null, like missing ones."""
    if isinstance(value, dict):
        return {k: _without_nan(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_without_nan(v) for v in value]
    if isinstance(value, float) and math.isnan(value):
        return None
    return value
