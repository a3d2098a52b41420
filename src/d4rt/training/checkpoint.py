"""Training checkpoints: written atomically, read back exactly, no pickles.

Layout of one checkpoint, ``<run>/checkpoints/step-00001000/``:

- ``model.safetensors`` + ``config.json``: the model, exactly as ``D4RT.save_pretrained`` writes it
  (``D4RT.from_pretrained`` opens the directory directly);
- ``optimizer.safetensors``: every optimiser state tensor, keyed ``<parameter name>/<state name>``
  (AdamW: ``step``, ``exp_avg``, ``exp_avg_sq``);
- ``optimizer.json``: the parameter groups (hyper-parameters and parameter names);
- ``ema/`` (with ``optim.ema_decay``): the averaged weights, a model directory like the checkpoint itself;
- ``trainer.json``, written last: step, data position, learning-rate schedule, the RNG states of every
  rank, the training config and the size of every other file.

Atomicity: everything is written into a hidden temporary directory (``.step-00001000.tmp-<pid>``), each
file and the directory are fsynced, then the directory is renamed to its final name and the parent
fsynced. A rename is atomic, so a ``step-*`` directory is always complete; a process killed mid-write
leaves only a temporary directory, which :func:`latest_checkpoint` never picks and
:func:`remove_temporaries` deletes. As a second guard, a checkpoint whose files do not have the sizes
recorded in ``trainer.json`` is skipped.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model.weights import CONFIG_NAME, WEIGHTS_NAME, save_checkpoint

FORMAT_VERSION = 1
OPTIMIZER_TENSORS = "optimizer.safetensors"
OPTIMIZER_GROUPS = "optimizer.json"
TRAINER_STATE = "trainer.json"
EMA_DIR = "ema"
_NAME = re.compile(r"^step-(\d{8,})$")


def checkpoint_name(step: int) -> str:
    return f"step-{step:08d}"


def write_checkpoint(root: str | Path, step: int, model_state: dict[str, torch.Tensor], model_config: D4RTConfig,
                     optimizer_state: dict, trainer_state: dict[str, Any],
                     ema_state: dict[str, torch.Tensor] | None = None) -> Path:
    """Write checkpoint ``step`` under ``root`` atomically and return its directory.

    model_state: full model state dict (CPU tensors); optimizer_state: full optimiser state dict as
    ``torch.distributed.checkpoint.state_dict.get_optimizer_state_dict`` returns it (``state`` keyed by
    parameter name); trainer_state: JSON-serialisable training state (see :mod:`d4rt.training.trainer`);
    ema_state: the full state dict of the averaged weights, written as the model directory ``ema/``.
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    final = root / checkpoint_name(step)
    temp = root / f".{final.name}.tmp-{os.getpid()}"
    if temp.exists():
        shutil.rmtree(temp)
    # save_checkpoint only reads ``.state_dict()``: hand it the already gathered full state.
    save_checkpoint(SimpleNamespace(state_dict=lambda: model_state), model_config, temp)
    tensors, groups = _split_optimizer_state(optimizer_state)
    save_file(tensors, str(temp / OPTIMIZER_TENSORS), metadata={"format": "pt"})
    _write_json(temp / OPTIMIZER_GROUPS, groups)
    if ema_state is not None:
        save_checkpoint(SimpleNamespace(state_dict=lambda: ema_state), model_config, temp / EMA_DIR)
    files = {p.relative_to(temp).as_posix(): p.stat().st_size for p in sorted(temp.rglob("*")) if p.is_file()}
    _write_json(temp / TRAINER_STATE, {**trainer_state, "format_version": FORMAT_VERSION, "step": step,
                                       "files": files})
    for path in sorted(temp.rglob("*"), reverse=True):  # files before the directories that hold them
        _fsync(path)
    _fsync(temp)
    if final.exists():  # a checkpoint of the same step from an earlier attempt: replace it
        shutil.rmtree(final)
    os.rename(temp, final)
    _fsync(root)
    return final


def latest_checkpoint(root: str | Path) -> Path | None:
    """The complete checkpoint of the highest step under ``root``, or None. Temporary directories and
    checkpoints whose files do not match their recorded sizes are ignored."""
    root = Path(root)
    if not root.is_dir():
        return None
    found = sorted(((int(m.group(1)), p) for p in root.iterdir() if (m := _NAME.match(p.name)) and p.is_dir()),
                   reverse=True)
    for _, path in found:
        if is_complete(path):
            return path
    return None


def is_complete(path: Path) -> bool:
    """Whether ``path`` holds a checkpoint whose trainer state parses and whose files have their sizes."""
    try:
        state = json.loads((path / TRAINER_STATE).read_text())
        files = state["files"]
        return all((path / name).stat().st_size == size for name, size in files.items()) and \
            all(name in files for name in (WEIGHTS_NAME, CONFIG_NAME, OPTIMIZER_TENSORS, OPTIMIZER_GROUPS))
    except (OSError, ValueError, KeyError, TypeError):
        return False


def read_checkpoint(path: str | Path) -> tuple[dict[str, torch.Tensor], dict, dict[str, Any]]:
    """``(model_state, optimizer_state, trainer_state)`` of a checkpoint written by :func:`write_checkpoint`."""
    path = Path(path)
    if not is_complete(path):
        raise UserError(f"{path} is not a complete training checkpoint")
    try:
        model_state = load_file(str(path / WEIGHTS_NAME))
        tensors = load_file(str(path / OPTIMIZER_TENSORS))
    except (SafetensorError, OSError) as err:
        raise UserError(f"cannot read checkpoint {path}: {err}") from None
    groups = json.loads((path / OPTIMIZER_GROUPS).read_text())
    trainer_state = json.loads((path / TRAINER_STATE).read_text())
    if trainer_state.get("format_version") != FORMAT_VERSION:
        raise UserError(f"checkpoint {path} has format version {trainer_state.get('format_version')}, "
                        f"this d4rt reads {FORMAT_VERSION}")
    return model_state, _join_optimizer_state(tensors, groups), trainer_state


def read_ema(path: str | Path) -> dict[str, torch.Tensor] | None:
    """The averaged weights of a complete checkpoint (its ``ema/`` directory), or None if it has none."""
    weights = Path(path) / EMA_DIR / WEIGHTS_NAME
    if not weights.is_file():
        return None
    try:
        return load_file(str(weights))
    except (SafetensorError, OSError) as err:
        raise UserError(f"cannot read the averaged weights {weights}: {err}") from None


def prune_checkpoints(root: str | Path, keep: int) -> None:
    """Delete all but the ``keep`` newest complete checkpoints under ``root``."""
    root = Path(root)
    steps = sorted((int(m.group(1)), p) for p in root.iterdir() if (m := _NAME.match(p.name)))
    for _, path in steps[:-keep]:
        shutil.rmtree(path, ignore_errors=True)


def remove_temporaries(root: str | Path) -> None:
    """Delete temporary directories left by a writer that was killed."""
    root = Path(root)
    if root.is_dir():
        for path in root.iterdir():
            if path.name.startswith(".step-") and ".tmp-" in path.name:
                shutil.rmtree(path, ignore_errors=True)


def write_file_atomically(path: Path, data: bytes) -> None:
    """Replace ``path`` with ``data`` so that readers see the old or the new file, never a partial one."""
    temp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(temp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(temp, path)


# ----------------------------------------------------------------------------------------- helpers
def _split_optimizer_state(state: dict) -> tuple[dict[str, torch.Tensor], dict]:
    tensors, scalars = {}, {}
    for name, entries in state["state"].items():
        for key, value in entries.items():
            if torch.is_tensor(value):
                tensors[f"{name}/{key}"] = value.detach().contiguous().cpu()
            else:
                scalars.setdefault(name, {})[key] = value
    return tensors, {"param_groups": state["param_groups"], "state_scalars": scalars}


def _join_optimizer_state(tensors: dict[str, torch.Tensor], groups: dict) -> dict:
    state: dict[str, dict] = {}
    for key, value in tensors.items():
        name, _, entry = key.rpartition("/")
        state.setdefault(name, {})[entry] = value
    for name, entries in groups["state_scalars"].items():
        state.setdefault(name, {}).update(entries)
    # JSON turns tuples (AdamW's betas) into lists; give them back their type.
    param_groups = [{k: (tuple(v) if isinstance(v, list) and k != "params" else v) for k, v in g.items()}
                    for g in groups["param_groups"]]
    return {"state": state, "param_groups": param_groups}


def _write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
