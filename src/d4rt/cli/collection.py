"""``d4rt reconstruct`` over many videos: one output folder per input, a summary, sharded across the
processes of ``torchrun``, resumable.

Inputs: several paths, a folder of video files, a glob pattern, or a ``.txt`` file listing paths (one per
line, ``#`` comments, relative paths from the list's folder). Each input is written to
``OUT_DIR/<its name>/`` exactly as a single ``d4rt reconstruct`` would write it, and ``OUT_DIR/summary.jsonl``
gets one row per input: ``input``, ``output``, ``status`` (``done`` this run, ``complete`` from an earlier
run, ``failed``), ``frames``, ``seconds``, ``error`` (the one-line reason of a failure).

Under ``torchrun --nproc_per_node N [--nnodes M]`` every rank loads the model once and takes the inputs
``rank, rank + N, ...`` of the list (NCCL on GPUs, gloo on CPU); rank 0 writes the summary after all are
done. A re-run skips inputs whose output folder exists (folders appear atomically, so one that exists is
complete) and inputs an earlier run recorded as failed, unless ``--retry-failed``; one input that fails
never stops the others.
"""

from __future__ import annotations

import glob
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from d4rt.errors import UserError
from d4rt.io.frames import IMAGE_SUFFIXES, VIDEO_SUFFIXES
from d4rt.progress import progress_bar, write_line

SUMMARY = "summary.jsonl"
LIST_SUFFIX = ".txt"


@dataclass
class Row:
    """One input's line of summary.jsonl."""

    input: str
    output: str
    status: str  # "done", "complete" or "failed"
    frames: int | None = None
    seconds: float | None = None
    error: str | None = None


def is_collection(items: list[str]) -> bool:
    """Whether the command line names many videos rather than one (a video file, image folder or array)."""
    if len(items) != 1:
        return True
    item = items[0]
    if _is_pattern(item) or item.lower().endswith(LIST_SUFFIX):
        return True
    return _is_video_folder(Path(item))


def expand_inputs(items: list[str]) -> list[Path]:
    """Every video the items name, in order, each once: (N,) paths. A folder of video files gives its
    videos (sorted by name); a folder of images is one video; a pattern gives its matches (sorted); a .txt
    file the paths it lists. Nothing found is a UserError naming the item."""
    found: list[Path] = []
    for item in items:
        if _is_pattern(item):
            matches = sorted(Path(m) for m in glob.glob(item))
            if not matches:
                raise UserError(f"{item}: no file matches this pattern")
            found += matches
        elif item.lower().endswith(LIST_SUFFIX):
            found += _read_list(Path(item))
        elif _is_video_folder(Path(item)):
            found += _videos_in(Path(item))
        else:
            found.append(Path(item))
    unique = list(dict.fromkeys(p.resolve() for p in found))
    if not unique:
        raise UserError("no input videos found")
    return unique


def output_names(inputs: list[Path]) -> list[str]:
    """One folder name per input: its file name without the suffix, made unique by ``_2``, ``_3``, ... in
    list order (so a re-run gives every input the same folder)."""
    names, seen = [], {}
    for path in inputs:
        stem = path.stem if path.suffix else path.name
        count = seen.get(stem, 0) + 1
        seen[stem] = count
        names.append(stem if count == 1 else f"{stem}_{count}")
    return names


def run_collection(inputs: list[Path], out_dir: Path, reconstruct_one: Callable[[Path, Path], int], *,
                   rank: int = 0, world_size: int = 1, barrier: Callable[[], None] = lambda: None,
                   overwrite: bool = False, retry_failed: bool = False) -> list[Row]:
    """Reconstruct this rank's share of ``inputs`` into ``out_dir`` and (rank 0) write the summary.

    reconstruct_one(input, output folder) -> frames reconstructed; it raises on failure (a UserError's
    message becomes the row's error line, any other exception its type and message). ``barrier`` waits
    for every rank (torch.distributed's under torchrun). Returns the summary's rows (rank 0; other ranks:
    their own rows).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    names = output_names(inputs)
    earlier = {row["input"]: row for row in _read_summary(out_dir / SUMMARY)}
    mine = list(range(rank, len(inputs), world_size))
    rank_file = out_dir / f".{SUMMARY}.rank-{rank}"
    rank_file.unlink(missing_ok=True)
    rows = []
    bar = progress_bar(mine, desc=f"videos (rank {rank})" if world_size > 1 else "videos", unit="video")
    for i in bar:
        source, target = inputs[i], out_dir / names[i]
        row = _decide(source, target, earlier.get(str(source)), overwrite, retry_failed)
        if row is None:
            start = time.perf_counter()
            try:
                frames = reconstruct_one(source, target)
                row = Row(str(source), str(target), "done", frames, round(time.perf_counter() - start, 3))
            except UserError as err:
                row = Row(str(source), str(target), "failed", seconds=round(time.perf_counter() - start, 3),
                          error=str(err))
            except Exception as err:  # one broken input must not stop the others: recorded, not raised
                row = Row(str(source), str(target), "failed", seconds=round(time.perf_counter() - start, 3),
                          error=f"{type(err).__name__}: {err}")
            if row.status == "failed":
                write_line(f"d4rt: {source}: failed: {row.error}")
        rows.append(row)
        with open(rank_file, "a") as fh:  # a killed run keeps what it finished
            fh.write(json.dumps(asdict(row)) + "\n")
    barrier()
    if rank != 0:
        return rows
    by_input = {}
    for r in range(world_size):
        path = out_dir / f".{SUMMARY}.rank-{r}"
        by_input.update({row["input"]: Row(**row) for row in _read_summary(path)})
        path.unlink(missing_ok=True)
    rows = [by_input[str(p)] for p in inputs]
    text = "".join(json.dumps(asdict(row)) + "\n" for row in rows)
    temp = out_dir / f".{SUMMARY}.tmp"
    temp.write_text(text)
    temp.replace(out_dir / SUMMARY)
    counts = {s: sum(row.status == s for row in rows) for s in ("done", "complete", "failed")}
    write_line(f"d4rt reconstruct: {len(rows)} videos: {counts['done']} reconstructed, {counts['complete']} already "
               f"complete, {counts['failed']} failed; summary in {out_dir / SUMMARY}")
    return rows


def _decide(source: Path, target: Path, earlier: dict | None, overwrite: bool, retry_failed: bool) -> Row | None:
    """The row of an input that is not to be reconstructed this run, or None if it is."""
    if overwrite:
        return None
    if target.is_dir():  # output folders appear atomically: one that exists is complete
        row = Row(str(source), str(target), "complete")
        if earlier and earlier.get("status") in ("done", "complete"):
            row.frames, row.seconds = earlier.get("frames"), earlier.get("seconds")
        return row
    if earlier and earlier.get("status") == "failed" and not retry_failed:
        return Row(str(source), str(target), "failed", earlier.get("frames"), earlier.get("seconds"),
                   earlier.get("error"))
    return None


def _read_summary(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _read_list(path: Path) -> list[Path]:
    if not path.is_file():
        raise UserError(f"{path} does not exist")
    entries = []
    for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if line:
            entry = Path(line).expanduser()
            entry = entry if entry.is_absolute() else path.parent / entry
            if not entry.exists():  # a wrong list is a wrong input: refused before any work
                raise UserError(f"{path} line {number}: {entry} does not exist")
            entries.append(entry)
    if not entries:
        raise UserError(f"{path} lists no input")
    return entries


def _is_pattern(item: str) -> bool:
    return any(c in item for c in "*?[") and not Path(item).exists()


def _is_video_folder(path: Path) -> bool:
    """A folder of video files (and no images: a folder of images is one video)."""
    return path.is_dir() and bool(_videos_in(path)) and not _images_in(path)


def _videos_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)


def _images_in(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
