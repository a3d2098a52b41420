"""The training loop: the same code on one CPU process, one GPU, or many under torchrun (DDP / FSDP).

One optimiser step = ``run.grad_accum`` micro-batches of ``data.batch_size`` clips on every rank. Per
step: set the scheduled learning rate, forward + loss + backward per micro-batch (bf16 autocast on GPU;
gradient sync only on the last micro-batch), clip the gradient norm, optimiser step (AdamW; with
``optim.muon`` Muon too). Every ``run.log_every`` steps the loss terms (averaged over ranks and micro-batches),
learning rate, gradient norm and throughput are logged; every ``validation.every`` steps the model (with
``optim.ema_decay``: the average of its weights) is validated on held-out clips; every ``run.checkpoint_every``
steps (and at the end) a checkpoint is written atomically and its weights are published as
``<run>/model.safetensors`` + ``<run>/config.json``.

Run directory::

    <run>/model.safetensors, config.json   latest weights (D4RT.from_pretrained(<run>))
    <run>/train_config.yaml                 the resolved training config
    <run>/checkpoints/step-XXXXXXXX/        resumable checkpoints (see d4rt.training.checkpoint)
    <run>/ema/                              with optim.ema_decay: the latest averaged weights (d4rt.training.ema)
    <run>/best/                             with validation.keep_best: the best-validated weights, best.json
    <run>/metrics.jsonl, tensorboard/       logs

``train(config, out, resume=True)`` continues from the newest complete checkpoint exactly: the weights,
optimiser state, step, data position and random-generator states are restored, so a run that is killed
and resumed ends with the same weights as one that was not (bitwise on CPU with fixed seeds). SIGTERM or
SIGINT (preemption, ``kill``, Ctrl-C) stops the run after the current step with a checkpoint of that
step, so nothing is lost (:mod:`d4rt.training.stop`).
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.distributed as dist

from d4rt.config import D4RTConfig
from d4rt.devices import native_bf16
from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.weights import ADDABLE_PARTS, CONFIG_NAME, WEIGHTS_NAME, check_state_dict
from d4rt.training import checkpoint as ckpt
from d4rt.training.config import TrainConfig
from d4rt.training.data import SampleStream, model_inputs, training_loader
from d4rt.training.distributed import (
    DistributedContext,
    gradient_sync,
    load_model_state,
    load_optimizer_state,
    model_state,
    optimizer_state,
    resolve_strategy,
    unwrap,
    wrap_model,
)
from d4rt.training.ema import WeightAverage
from d4rt.training.logger import TrainLogger
from d4rt.training.losses import d4rt_loss
from d4rt.training.optimization import build_optimizer, freeze_parameters, learning_rate, set_learning_rate
from d4rt.training.randomness import capture_rng_state, restore_rng_state, seed_rank
from d4rt.training.stop import StopRequest
from d4rt.training.validation import Validator

# Config fields that may change when a run is resumed: they do not alter the training trajectory
# (run.max_steps only extends or shortens it; run.device and data.dataset.render_device only the last bits
# of float rounding, so a run started on a GPU machine can go on on a CPU one).
RESUMABLE_CHANGES = ("run.max_steps", "run.log_every", "run.checkpoint_every", "run.keep_checkpoints",
                     "run.tensorboard", "run.progress", "run.device", "data.workers", "data.dataset.render_device",
                     "validation.")


@dataclass
class TrainResult:
    """What a run returns: the run directory, steps done, the last logged scalars, and the signal that
    stopped it early (``"SIGTERM"`` / ``"SIGINT"``: a checkpoint of ``step`` was written) or None."""

    out: Path
    step: int
    metrics: dict[str, float]
    stopped_by: str | None = None


def train(config: TrainConfig, out: str | Path, resume: bool = False) -> TrainResult:
    """Train ``config`` into the run directory ``out`` (see the module docstring).

    Joins the process group when launched by torchrun. ``resume=True`` continues from the newest
    complete checkpoint in ``out`` (or starts afresh when there is none); without it, a run directory
    that already holds checkpoints is refused.
    """
    config.validate()
    context = DistributedContext.from_environment(config.run.device)
    trainer = Trainer(config, out, context)
    try:
        return trainer.fit(resume)
    finally:
        trainer.model = trainer.optimizer = None  # a DDP model must go before its process group
        context.close()


class Trainer:
    """One training run in one process of ``context``; after :meth:`fit`, ``model`` (as wrapped for the
    strategy) and ``optimizer`` hold the final state."""

    def __init__(self, config: TrainConfig, out: str | Path, context: DistributedContext):
        self.model: torch.nn.Module | None = None
        self.optimizer: torch.optim.Optimizer | None = None
        self.ema: WeightAverage | None = None
        self.config = config
        self.model_config: D4RTConfig = config.validate()
        self.out = Path(out)
        self.context = context
        self.strategy = resolve_strategy(config.run.strategy, context)
        # auto: bf16 where the device computes it natively (the recipe study measured the same loss per step
        # as fp32 on an AMX CPU, and more steps per minute); emulated bf16 would be slower than fp32.
        native = native_bf16(context.device)
        bf16 = config.run.precision == "bf16" or (config.run.precision == "auto" and native)
        self.autocast = torch.autocast(context.device.type, dtype=torch.bfloat16, enabled=bf16)
        # An explicit bf16 is obeyed, but said once: on an AVX2-only CPU it ran 9x slower than fp32 (stage 30).
        self.emulated_bf16_warning = None if native or not bf16 else (
            f"run.precision bf16 on {context.device.type}, which has no native bfloat16 (AMX-BF16, AVX512-BF16 or a "
            f"bf16 GPU): autocast is emulated and can be several times slower than fp32; precision auto picks fp32 here")

    # ------------------------------------------------------------------------------------------ set-up
    def _build_model(self) -> torch.nn.Module:
        spec, run = self.config.model, self.config.run
        torch.manual_seed(run.seed)  # the same initial weights on every rank
        pretrained = None
        if spec.init_from is not None:
            with torch.random.fork_rng(devices=[]):  # building it must not move the seeded stream the new model draws
                pretrained = D4RT.from_pretrained(spec.init_from)
        if pretrained is not None and "motion_threshold" not in spec.overrides:
            # The motion-mask threshold is calibrated on trained weights (tools/motion_mask_probe.py), not learned:
            # a run from a checkpoint keeps the checkpoint's unless the config sets its own.
            self.model_config = self.model_config.replace(motion_threshold=pretrained.config.motion_threshold)
        model = D4RT(self.model_config)
        if pretrained is not None:
            state = pretrained.state_dict()
            had_residual, wants_residual = pretrained.config.uv_residual, self.model_config.uv_residual
            # The differences allowed: adding a part of ADDABLE_PARTS (the relative-pose head, the dense depth head),
            # turning the 2D head residual and restricting more heads to the target frame (never undoing any). The
            # camera pairing, flip averaging and motion threshold are inference defaults, and the frames RGB patches
            # are cut from an input choice, not architecture: the new model keeps its own (the motion threshold
            # came from the checkpoint above unless the config sets one).
            wanted = {flag: getattr(self.model_config, flag) for flag in ADDABLE_PARTS}
            dropped = any(getattr(pretrained.config, flag) > wants for flag, wants in wanted.items())
            frame_heads = self.model_config.target_frame_heads
            same = pretrained.config.replace(uv_residual=wants_residual, pose_pairs=self.model_config.pose_pairs,
                                             flip_average=self.model_config.flip_average,
                                             rgb_patch_source=self.model_config.rgb_patch_source,
                                             motion_threshold=self.model_config.motion_threshold,
                                             target_frame_heads=frame_heads, **wanted)
            if (same != self.model_config or dropped or had_residual > wants_residual
                    or pretrained.config.target_frame_heads > frame_heads):
                raise UserError(f"model.init_from {spec.init_from} has a different model config than model.preset "
                                f"{spec.preset!r} with its overrides")
            for flag, prefix in ADDABLE_PARTS.items():  # a part the checkpoint lacks keeps its fresh (seeded) weights
                if wanted[flag] and not getattr(pretrained.config, flag):
                    state.update({k: v for k, v in model.state_dict().items() if k.startswith(prefix)})
            if wants_residual and not had_residual:  # a head trained on absolute (u, v) starts at zero: no motion
                state.update({k: torch.zeros_like(v) for k, v in state.items() if k.startswith("decoder.heads.heads.uv.")})
            model.load_state_dict(state, strict=True)
        if spec.videomae is not None:
            from d4rt.model.videomae import load_videomae_v2

            load_videomae_v2(model, spec.videomae)
        freeze_parameters(model, self.config.optim.freeze)  # before wrapping: DDP and FSDP read requires_grad then
        return wrap_model(model.train(), self.strategy, self.context)

    def _check_run_directory(self, resume: bool) -> Path | None:
        """Rank 0 finds the newest complete checkpoint (the run directory need only exist there); a run
        directory with checkpoints is refused on every rank unless resuming."""
        root = self.out / "checkpoints"
        latest = None
        if self.context.is_main:
            ckpt.remove_temporaries(root)
            latest = ckpt.latest_checkpoint(root)
        if self.context.broadcast_flag(latest is not None and not resume):
            raise UserError(f"{self.out} already holds checkpoints; pass --resume to continue that run or choose "
                            f"another --out")
        return latest

    def _restore(self, model, optimizer, latest: Path | None) -> dict:
        """Load the checkpoint ``latest`` (read on rank 0, broadcast) -> trainer state (``{}`` if fresh)."""
        context = self.context
        found = context.broadcast_flag(latest is not None)
        if not found:
            return {}
        decay = self.config.optim.ema_decay
        model_tensors, optim_state, state, averaged = ({}, {}, None, {})
        if context.is_main:
            model_tensors, optim_state, state = ckpt.read_checkpoint(latest)
            _check_resumable(state["config"], self.config.to_dict(), latest)
            check_state_dict(unwrap(model), model_tensors, f"checkpoint {latest}")
            if decay is not None:
                averaged = ckpt.read_ema(latest)
                if averaged is None:
                    raise UserError(f"checkpoint {latest} has no averaged weights (ema/) although "
                                    "optim.ema_decay is set")
                check_state_dict(unwrap(model), averaged, f"averaged weights of checkpoint {latest}")
        if context.distributed:
            box = [state]
            dist.broadcast_object_list(box, src=0)
            state = box[0]
        if decay is not None:  # through the model, which shards and broadcasts the average as it should
            load_model_state(model, averaged, context)
            # one update per applied optimiser step
            self.ema = WeightAverage(model, decay, int(state["step"]) - int(state["skipped_steps"]))
        load_model_state(model, model_tensors, context)
        load_optimizer_state(model, optimizer, optim_state, context)
        ranks = state["rng"]
        if len(ranks) == context.world_size:
            restore_rng_state(ranks[context.rank], context.device)
        return state

    # ------------------------------------------------------------------------------------------ loop
    def fit(self, resume: bool = False) -> TrainResult:
        cfg, context = self.config, self.context
        latest = self._check_run_directory(resume)
        model = self.model = self._build_model()
        optimizer = self.optimizer = build_optimizer(model, cfg.optim)
        seed_rank(cfg.run.seed, context.rank)
        state = self._restore(model, optimizer, latest)  # restores the average of a resumed run
        if cfg.optim.ema_decay is not None and self.ema is None:
            self.ema = WeightAverage(model, cfg.optim.ema_decay)
        step = int(state.get("step", 0))
        next_sample = int(state.get("next_sample", 0))
        skipped = int(state.get("skipped_steps", 0))
        if context.is_main:
            self.out.mkdir(parents=True, exist_ok=True)
            (self.out / "train_config.yaml").write_text(cfg.to_yaml())
            _truncate_metrics(self.out / "metrics.jsonl", step)

        data, run = cfg.data, cfg.run
        dataset = data.build_dataset(str(context.device), patch_frames=self.model_config.patches_from_original)
        stream = SampleStream(len(dataset), run.seed, next_sample, data.batch_size, run.grad_accum, context.rank,
                              context.world_size, echo=data.dataset.echo if data.tracks is None else 1)
        loader = training_loader(dataset, stream, data.workers, run.seed, context.rank,
                                 pin_memory=context.device.type == "cuda",
                                 spawn=data.tracks is None and data.dataset.renders_on_gpu)
        validator = Validator(cfg.validation, cfg.loss, data.dataset.sampler) if cfg.validation.every else None
        best = _read_best(self.out, cfg.validation) if context.is_main else None
        logger = TrainLogger(self.out, context.is_main, run.max_steps, step, run.tensorboard, run.progress)
        if latest is not None and context.is_main:
            logger.message(f"resumed from {latest} at step {step}")
        if self.emulated_bf16_warning is not None and context.is_main:
            logger.message(self.emulated_bf16_warning)

        totals: dict[str, torch.Tensor] = {}
        last: dict[str, float] = {}
        window_start, window_steps = time.perf_counter(), 0
        with StopRequest() as stop:
            batches = iter(loader)  # starts the workers under the stop handlers (they leave stopping to us)
            try:
                while step < run.max_steps:
                    lr = learning_rate(step, cfg.optim, run.max_steps)
                    set_learning_rate(optimizer, lr)
                    for micro in range(run.grad_accum):
                        batch = {k: v.to(context.device, non_blocking=True) for k, v in next(batches).items()}
                        with gradient_sync(model, micro == run.grad_accum - 1):
                            with self.autocast:
                                out = model(batch["video"], batch["queries"], batch["aspect_ratio"],
                                            attention_block=cfg.loss.attention_block,
                                            **model_inputs(self.model_config, batch))
                            loss, terms = d4rt_loss(out, batch, cfg.loss)
                            (loss / run.grad_accum).backward()
                        for key, value in terms.items():
                            totals[key] = totals.get(key, 0.0) + value / run.grad_accum
                    norm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.optim.grad_clip)
                    norm = norm.full_tensor() if hasattr(norm, "full_tensor") else norm  # FSDP: a DTensor
                    if torch.isfinite(norm):
                        optimizer.step()
                        if self.ema is not None:
                            self.ema.update()
                    else:  # the same decision on every rank: the norm is of the synchronised gradients
                        skipped += 1
                        logger.message(f"step {step}: non-finite gradient norm, update skipped")
                    optimizer.zero_grad(set_to_none=True)
                    step += 1
                    next_sample += stream.samples_per_step
                    window_steps += 1
                    totals["grad_norm"] = totals.get("grad_norm", 0.0) + norm.detach().float()

                    if step % run.log_every == 0 or step == run.max_steps:
                        averaged = context.mean(totals)
                        elapsed = time.perf_counter() - window_start
                        clips_per_s = window_steps * stream.samples_per_step / elapsed
                        last = {f"loss/{k}": v / window_steps for k, v in averaged.items() if k != "grad_norm"}
                        last.update({"grad_norm": averaged["grad_norm"] / window_steps, "lr": lr,
                                     "throughput/clips_per_s": clips_per_s,
                                     "throughput/queries_per_s": clips_per_s * data.num_queries,
                                     "skipped_steps": float(skipped)})
                        logger.log(step, last)
                        totals, window_start, window_steps = {}, time.perf_counter(), 0
                    paused = time.perf_counter()  # validation and checkpoints do not count as training time
                    improved = False
                    if validator is not None and (step % cfg.validation.every == 0 or step == run.max_steps):
                        scalars = self._validate(model, validator)
                        logger.log(step, scalars)
                        last.update(scalars)
                        if validator.failures:
                            logger.message(f"validation at step {step}: {len(validator.failures)} of "
                                           f"{len(validator.clips)} clips could not be reconstructed and are left "
                                           f"out of its benchmark metrics ({validator.failures[0]})")
                        if cfg.validation.keep_best is not None:
                            improved = self._improves_best(best, scalars)
                    scheduled = step % run.checkpoint_every == 0 or step == run.max_steps
                    if scheduled or improved:
                        path = self._save(model, optimizer, step, next_sample, skipped)
                        if improved and context.is_main:
                            best = _publish_best(path, self.out, step, last, cfg.validation)
                    window_start += time.perf_counter() - paused
                    logger.advance()
                    if context.any_flag(stop.requested is not None):  # every rank stops after the same step
                        if not (scheduled or improved):
                            self._save(model, optimizer, step, next_sample, skipped)
                        stopped_by = stop.requested or "a signal to another rank"
                        logger.message(f"stopped by {stopped_by} after step {step}: checkpoint written, continue with "
                                       "--resume")
                        return TrainResult(self.out, step, last, stopped_by)
            finally:
                del batches  # shuts the workers down now (they end on their own), not when this frame goes
                logger.close()
        return TrainResult(self.out, step, last)

    # ------------------------------------------------------------------------------------------ outputs
    def _validate(self, model, validator: Validator) -> dict[str, float]:
        """Validation on rank 0 with an unsharded model (FSDP: gathered into a plain copy)."""
        if self.ema is not None:
            with self.ema.swapped_in():
                return self._validate_weights(model, validator)
        return self._validate_weights(model, validator)

    def _validate_weights(self, model, validator: Validator) -> dict[str, float]:
        scalars: dict[str, float] = {}
        if self.strategy == "fsdp":
            full = model_state(model)  # collective
            if self.context.is_main:
                plain = D4RT(self.model_config).to(self.context.device)
                plain.load_state_dict(full, strict=True)
                scalars = validator.run(plain, self.autocast)
                del plain
        elif self.context.is_main:
            scalars = validator.run(unwrap(model), self.autocast)
        self.context.barrier()
        return scalars

    def _improves_best(self, best: dict | None, scalars: dict[str, float]) -> bool:
        """Whether this validation sets a new best of ``validation.keep_best``, the same answer on every rank
        (only the main rank validates, so every rank saves the same step); an unknown metric name is a
        one-line error on every rank rather than on the main rank alone while the others wait."""
        validation, context = self.config.validation, self.context
        key = f"val/{validation.keep_best}"
        # A validation that could not reconstruct every clip scored its metrics on fewer clips (or none): it
        # cannot set a best of them. Its loss terms cover every clip.
        incomplete = (scalars.get("val/reconstruction_failures", 0.0) > 0
                      and not validation.keep_best.startswith("loss/"))
        if context.any_flag(context.is_main and incomplete):
            return False
        if context.any_flag(context.is_main and key not in scalars):
            names = ", ".join(sorted(k.removeprefix("val/") for k in scalars))
            raise UserError(f"validation.keep_best {validation.keep_best!r} is not a validation metric"
                            + (f"; choose from {names}" if names else ""))
        return context.any_flag(context.is_main and _beats(best, scalars[key], validation.keep_best_mode))

    def _save(self, model, optimizer, step: int, next_sample: int, skipped: int) -> Path | None:
        """Checkpoint this step (a collective); its directory on the main rank, None on the others."""
        context = self.context
        weights, optim = model_state(model), optimizer_state(model, optimizer)  # collectives
        averaged = None
        if self.ema is not None:
            with self.ema.swapped_in():
                # a collective; copied, because on one CPU process the state dict shares the parameters' storage
                averaged = {name: value.clone() for name, value in model_state(model).items()}
        rng = capture_rng_state(context.device)
        if context.distributed:
            ranks = [None] * context.world_size
            dist.all_gather_object(ranks, rng)
        else:
            ranks = [rng]
        if context.is_main:
            trainer_state = {"step": step, "next_sample": next_sample, "skipped_steps": skipped,
                             "world_size": context.world_size, "strategy": self.strategy,
                             "lr": learning_rate(step - 1, self.config.optim, self.config.run.max_steps),
                             "rng": ranks, "config": self.config.to_dict()}
            root = self.out / "checkpoints"
            path = ckpt.write_checkpoint(root, step, weights, self.model_config, optim, trainer_state, averaged)
            _publish_weights(path, self.out)
            if averaged is not None:
                _publish_weights(path / ckpt.EMA_DIR, self.out / ckpt.EMA_DIR)
            ckpt.prune_checkpoints(root, self.config.run.keep_checkpoints)
        context.barrier()
        return path if context.is_main else None


def _publish_weights(checkpoint: Path, out: Path) -> None:
    """Make ``out/model.safetensors`` and ``out/config.json`` the checkpoint's, each replaced atomically
    (hard links: checkpoint files are never modified, only deleted)."""
    out.mkdir(exist_ok=True)
    for name in (WEIGHTS_NAME, CONFIG_NAME):
        temp = out / f".{name}.tmp-{os.getpid()}"
        temp.unlink(missing_ok=True)
        try:
            os.link(checkpoint / name, temp)
        except OSError:  # file systems without hard links
            ckpt.write_file_atomically(temp, (checkpoint / name).read_bytes())
        os.replace(temp, out / name)


BEST = "best"  # <run>/best/: validation.keep_best's weights


def _read_best(out: Path, validation) -> dict | None:
    """The best-validated record of a resumed run (``<run>/best/best.json``), None if there is none yet or it
    ranks another metric or direction (a resume may change validation.keep_best: the record starts again)."""
    path = out / BEST / "best.json"
    if validation.keep_best is None or not path.is_file():
        return None
    record = json.loads(path.read_text())
    same = record.get("metric") == validation.keep_best and record.get("mode") == validation.keep_best_mode
    return record if same else None


def _beats(best: dict | None, value: float, mode: str) -> bool:
    """Whether ``value`` beats the best record so far in direction ``mode`` (a NaN never does)."""
    if math.isnan(value):
        return False
    return best is None or (value < best["value"] if mode == "min" else value > best["value"])


def _publish_best(checkpoint: Path, out: Path, step: int, scalars: dict[str, float], validation) -> dict:
    """Publish ``checkpoint``'s validated weights (the average, where it holds one) as ``<run>/best/`` and
    record why; returns the record."""
    averaged = checkpoint / ckpt.EMA_DIR
    _publish_weights(averaged if averaged.is_dir() else checkpoint, out / BEST)
    record = {"metric": validation.keep_best, "mode": validation.keep_best_mode, "step": step,
              "value": scalars[f"val/{validation.keep_best}"]}
    ckpt.write_file_atomically(out / BEST / "best.json", (json.dumps(record, indent=1) + "\n").encode())
    return record


def _check_resumable(saved: dict, current: dict, path: Path) -> None:
    def flat(d: dict, prefix: str = "") -> dict:
        items = {}
        for k, v in d.items():
            items.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) and k != "overrides" else {f"{prefix}{k}": v})
        return items
    # A key the saved config lacks is an option added since it was written: it ran under that option's default.
    b = flat(current)
    a = {**{k: v for k, v in flat(TrainConfig().to_dict()).items() if k in b}, **flat(saved)}
    changed = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k) and not k.startswith(RESUMABLE_CHANGES))
    if changed:
        raise UserError(f"cannot resume {path}: the config changed in {', '.join(changed)} "
                        f"(only {', '.join(RESUMABLE_CHANGES)} may change)")


def _truncate_metrics(path: Path, step: int) -> None:
    """Drop records after ``step`` (logged by a run that was killed before its next checkpoint)."""
    if not path.is_file():
        return
    kept = [line for line in path.read_text().splitlines() if line and json.loads(line).get("step", 0) <= step]
    ckpt.write_file_atomically(path, "".join(line + "\n" for line in kept).encode())
