"""Training on several processes at once: torchrun's environment, one group, DDP.

``torchrun --nproc-per-node N -m perception.classify train ...`` starts N copies of the
command. Each joins the process group torchrun describes in its environment (``RANK``,
``WORLD_SIZE``, ``MASTER_ADDR``, ``MASTER_PORT``): gloo on the CPU, nccl with CUDA. Every
process draws the same batches from the same seed; each computes its share of every
batch (``shard``) and DDP averages the gradients, so the steps are those of one process
with the whole batch (up to batch norm, whose statistics are each process's own share's).
The first process (``leader``) prints, logs and saves; the checkpoint is the same format.
Alone (no ``WORLD_SIZE``, or 1), nothing here does anything.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn


@dataclass(frozen=True)
class Group:
    """This process's place among the training processes."""

    rank: int = 0
    size: int = 1

    @property
    def leader(self) -> bool:
        return self.rank == 0

    def shard(self, indices: np.ndarray) -> np.ndarray:
        """This process's share of a batch (every ``size``-th sample from ``rank``)."""
        return indices[self.rank :: self.size]

    def wrap(self, model: nn.Module) -> nn.Module:
        """The model as the training steps call it: DDP across the group, or itself."""
        if self.size == 1:
            return model
        from torch.nn.parallel import DistributedDataParallel

        return DistributedDataParallel(model)

    def total(self, values: list[float]) -> list[float]:
        """The sums of ``values`` over the group (each process's own when alone)."""
        if self.size == 1:
            return values
        tensor = torch.tensor(values, dtype=torch.float64)
        torch.distributed.all_reduce(tensor)
        return tensor.tolist()


def join_from_env() -> Group:
    """Join the group torchrun's environment describes; alone without one."""
    size = int(os.environ.get("WORLD_SIZE", "1"))
    if size <= 1:
        return Group()
    import torch.distributed as dist

    if not dist.is_initialized():
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    return Group(rank=dist.get_rank(), size=dist.get_world_size())


def leave(group: Group) -> None:
    """Leave the group (after the last collective step)."""
    if group.size > 1 and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()
