"""One process or many: process-group set-up, model wrapping (DDP / FSDP), and whole-model state.

The same training code runs as one plain process, on one GPU, or under ``torchrun`` (which sets
``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``/``MASTER_PORT``): the process group uses NCCL on
GPUs and gloo on CPUs. Strategies:

- ``single``: the model as it is (one process).
- ``ddp``: ``DistributedDataParallel``; every rank holds the whole model, gradients are all-reduced.
- ``fsdp``: ``torch.distributed.fsdp.fully_shard`` on every encoder block, then on the whole model
  (query embedding, decoder, heads and the encoder's stem). Parameters, gradients and optimiser state
  are sharded across ranks. The decoder stays in the root group because ``D4RT.forward`` projects the
  scene keys/values of every decoder block before running the blocks.

Checkpoints always hold full (unsharded) tensors gathered on rank 0, so they load in any strategy and
world size (:func:`model_state`, :func:`optimizer_state`, :func:`load_model_state`,
:func:`load_optimizer_state`).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist
from torch import nn
from torch.distributed.checkpoint.state_dict import (
    StateDictOptions,
    get_model_state_dict,
    get_optimizer_state_dict,
    set_model_state_dict,
    set_optimizer_state_dict,
)

from d4rt.errors import UserError


@dataclass
class DistributedContext:
    """Where this process sits: ``rank`` of ``world_size`` processes, its ``device``."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @classmethod
    def from_environment(cls, device: str = "auto", timeout_minutes: float = 30.0) -> "DistributedContext":
        """Read torchrun's variables (absent: one process), pick the device, join the process group.

        ``device``: ``auto`` (this rank's GPU ``cuda:LOCAL_RANK`` when CUDA is available, else CPU),
        ``cpu``, ``cuda`` or ``cuda:N``.
        """
        world_size = int(os.environ.get("WORLD_SIZE", "1"))
        rank = int(os.environ.get("RANK", "0"))
        local_rank = int(os.environ.get("LOCAL_RANK", "0"))
        if device == "auto":
            device = "cuda" if torch.cuda.is_available() else "cpu"
        if device.startswith("cuda"):
            if not torch.cuda.is_available():
                raise UserError(f"run.device is {device!r} but CUDA is not available")
            chosen = torch.device(device if ":" in device else f"cuda:{local_rank}")
            torch.cuda.set_device(chosen)
        elif device == "cpu":
            chosen = torch.device("cpu")
        else:
            raise UserError(f"run.device must be auto, cpu, cuda or cuda:N, got {device!r}")
        if world_size > 1 and not dist.is_initialized():
            backend = "nccl" if chosen.type == "cuda" else "gloo"
            kwargs = {"device_id": chosen} if chosen.type == "cuda" else {}
            dist.init_process_group(backend, timeout=timedelta(minutes=timeout_minutes), **kwargs)
        return cls(rank, world_size, local_rank, chosen)

    def close(self) -> None:
        """Leave the process group. Drop every reference to the wrapped model first: FSDP's device mesh
        holds the group, and a group still alive when the interpreter shuts down can abort the process."""
        if self.distributed and dist.is_initialized():
            dist.barrier()  # no rank tears the group down while another still talks to it
            release_device_meshes()
            dist.destroy_process_group()

    def barrier(self) -> None:
        if self.distributed:
            dist.barrier()

    def mean(self, values: dict[str, torch.Tensor]) -> dict[str, float]:
        """Average scalar tensors over ranks (one collective for all of them) -> Python floats."""
        keys = sorted(values)
        stacked = torch.stack([values[k].detach().float().reshape(()) for k in keys]).to(self.device)
        if self.distributed:
            dist.all_reduce(stacked, op=dist.ReduceOp.SUM)
            stacked /= self.world_size
        return dict(zip(keys, stacked.tolist()))

    def any_flag(self, flag: bool) -> bool:
        """True on every rank if ``flag`` is true on any rank (no collective when not distributed)."""
        if not self.distributed:
            return flag
        value = torch.tensor([1.0 if flag else 0.0], device=self.device)
        dist.all_reduce(value, op=dist.ReduceOp.MAX)
        return bool(value.item())

    def broadcast_flag(self, flag: bool) -> bool:
        """Rank 0's ``flag`` on every rank."""
        if not self.distributed:
            return flag
        value = torch.tensor([1.0 if flag else 0.0], device=self.device)
        dist.broadcast(value, src=0)
        return bool(value.item())


# (module, attribute path of a function that empties one of DTensor's caches that hold device meshes)
_DTENSOR_CACHES = (
    ("torch.distributed.tensor.debug", "_clear_sharding_prop_cache"),
    ("torch.distributed.tensor._redistribute", "clear_redistribute_planner_cache"),
    ("torch.distributed.tensor._redistribute", "_gen_transform_infos.cache_clear"),
    ("torch.distributed.tensor._collective_utils", "MeshTopoInfo.build_from_mesh.cache_clear"),
    ("torch.distributed.tensor", "DTensor._op_dispatcher.sharding_propagator._propagate_tensor_meta_cached.cache_clear"),
)


def release_device_meshes() -> None:
    """Free the device meshes of models already deleted, so that their process group goes with
    ``destroy_process_group`` (its gloo threads joined) and not at interpreter exit.

    Why: DTensor (FSDP's parameters) memoises sharding and redistribution plans in module-level caches
    whose keys hold the mesh, and the mesh holds the process group. Left alone, the group outlives
    ``destroy_process_group`` and is torn down during interpreter finalization, where gloo's worker
    threads occasionally abort the process ("terminate called without an active exception": a rank of
    the FSDP test died so in CI). These are torch's private caches (the README installs torch 2.13.0;
    pyproject leaves torch unpinned); one that a torch release renames is skipped, and the test worker
    checks that no mesh survives.
    """
    import gc
    import importlib

    for module, path in _DTENSOR_CACHES:
        try:
            target = importlib.import_module(module)
            for name in path.split("."):
                target = getattr(target, name)
            target()
        except (ImportError, AttributeError):
            pass
    gc.collect()  # FSDP modules sit in reference cycles: collect them now, not at exit


def resolve_strategy(strategy: str, context: DistributedContext) -> str:
    """``auto`` -> ``ddp`` with several processes, else ``single``; refuse impossible combinations."""
    if strategy == "auto":
        return "ddp" if context.distributed else "single"
    if strategy == "single" and context.distributed:
        raise UserError(f"run.strategy 'single' cannot run in {context.world_size} processes; use ddp or fsdp")
    if strategy in ("ddp", "fsdp") and not context.distributed:
        return "single"  # one process: nothing to distribute, same result
    return strategy


def wrap_model(model: nn.Module, strategy: str, context: DistributedContext) -> nn.Module:
    """Move ``model`` to the context's device and wrap it for ``strategy`` (see the module docstring)."""
    model = model.to(context.device)
    if strategy == "single":
        return model
    if strategy == "ddp":
        ids = [context.device.index] if context.device.type == "cuda" else None
        return nn.parallel.DistributedDataParallel(model, device_ids=ids)
    if strategy == "fsdp":
        from torch.distributed.fsdp import fully_shard

        for block in model.encoder.blocks:
            fully_shard(block)
        fully_shard(model)
        return model
    raise UserError(f"unknown strategy {strategy!r}")


def unwrap(model: nn.Module) -> nn.Module:
    """The D4RT module under a DDP wrapper (FSDP modifies the module in place: returned as is)."""
    return model.module if isinstance(model, nn.parallel.DistributedDataParallel) else model


def gradient_sync(model: nn.Module, enabled: bool) -> contextlib.AbstractContextManager:
    """Context for one micro-step: skip the gradient all-reduce / reduce-scatter unless ``enabled``
    (the last micro-step of an accumulation)."""
    if isinstance(model, nn.parallel.DistributedDataParallel) and not enabled:
        return model.no_sync()
    if hasattr(model, "set_requires_gradient_sync"):  # an FSDP module
        model.set_requires_gradient_sync(enabled)
    return contextlib.nullcontext()


def _full(**extra) -> StateDictOptions:
    return StateDictOptions(full_state_dict=True, cpu_offload=True, **extra)


def model_state(model: nn.Module) -> dict[str, torch.Tensor]:
    """Full model state dict on CPU on rank 0 (an empty dict on the other ranks); a collective."""
    return get_model_state_dict(unwrap(model), options=_full())


def optimizer_state(model: nn.Module, optimizer: torch.optim.Optimizer) -> dict:
    """Full optimiser state dict (``state`` keyed by parameter name) on CPU on rank 0; a collective. An
    :class:`~d4rt.training.optimization.OptimizerChain` gives one dict for all its optimisers."""
    return get_optimizer_state_dict(unwrap(model), _optimizers(optimizer), options=_full())


def load_model_state(model: nn.Module, state: dict[str, torch.Tensor], context: DistributedContext) -> None:
    """Load a full state dict read on rank 0 (other ranks pass ``{}``) into any wrapped model, strictly."""
    options = _full(broadcast_from_rank0=context.distributed, strict=True)
    set_model_state_dict(unwrap(model), state, options=options)


def load_optimizer_state(model: nn.Module, optimizer: torch.optim.Optimizer, state: dict,
                         context: DistributedContext) -> None:
    options = _full(broadcast_from_rank0=context.distributed)
    set_optimizer_state_dict(unwrap(model), _optimizers(optimizer), state, options=options)


def _optimizers(optimizer) -> torch.optim.Optimizer | tuple[torch.optim.Optimizer, ...]:
    """What torch's state-dict functions take: the optimiser, or every optimiser of a chain (AdamW and Muon)."""
    return getattr(optimizer, "optimizers", optimizer)
