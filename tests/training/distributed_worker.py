"""Run by ``torchrun`` in test_distributed.py: train a config, then report a digest of every parameter as
each rank sees it (FSDP: the full parameter gathered from the shards).

    torchrun --nproc_per_node 2 distributed_worker.py CONFIG.yaml OUT_DIR REPORT.json [--resume]
"""

import gc
import hashlib
import json
import sys

import torch
import torch.distributed as dist
from torch.distributed.device_mesh import DeviceMesh
from torch.distributed.checkpoint.state_dict import StateDictOptions, get_model_state_dict

from d4rt.training import TrainConfig
from d4rt.training.distributed import DistributedContext, unwrap
from d4rt.training.trainer import Trainer


def main(config_path: str, out: str, report: str, *flags: str) -> None:
    config = TrainConfig.load(config_path)
    context = DistributedContext.from_environment(config.run.device)
    trainer = Trainer(config, out, context)
    trainer.fit(resume="--resume" in flags)
    # Without cpu_offload every rank receives the full tensors.
    state = get_model_state_dict(unwrap(trainer.model), options=StateDictOptions(full_state_dict=True))
    digests = {name: hashlib.sha256(t.detach().cpu().contiguous().numpy().tobytes()).hexdigest()
               for name, t in state.items()}
    gathered = [None] * context.world_size
    dist.all_gather_object(gathered, {"strategy": trainer.strategy, "digests": digests,
                                      "threads": torch.get_num_threads()})
    if context.is_main:
        with open(report, "w") as fh:
            json.dump(gathered, fh)
    del trainer, state  # release the wrapped model before its process group
    context.close()
    # The process group must be gone before interpreter exit (see release_device_meshes): no mesh holds it.
    alive = [o for o in gc.get_objects() if isinstance(o, DeviceMesh)]
    if alive:
        sys.exit(f"rank {context.rank}: {len(alive)} device mesh(es) still alive after close()")


if __name__ == "__main__":
    main(*sys.argv[1:])
