"""Data-parallel training with ``torchrun``: each process owns its worlds, gradients are all-reduced.

Started by ``torchrun --nproc_per_node P -m dexmots_rl.apps.train ...`` (``WORLD_SIZE`` > 1), this
joins the process group (gloo on CPU, nccl on CUDA). Every rank steps its own ``task.num_envs`` worlds
with its own seed; the actor and critic gradients are averaged (``all_reduce``) before each optimiser
step and the observation statistics are merged, so parameters stay identical on all ranks. Rank 0
logs, checkpoints and evaluates. Without ``WORLD_SIZE`` every method is a cheap no-op.

Example:
    >>> d = Distributed.from_environment()   # single process
    >>> d.rank, d.world_size, d.is_main
    (0, 1, True)
"""

from __future__ import annotations

import os

import torch
import torch.distributed as torch_dist

__all__ = ["Distributed"]


class Distributed:
    def __init__(self, rank: int = 0, world_size: int = 1):
        self.rank, self.world_size = rank, world_size

    @classmethod
    def from_environment(cls) -> Distributed:
        world_size = int(os.environ.get("WORLD_SIZE", "1"))
        if world_size <= 1:
            return cls()
        if not torch_dist.is_initialized():
            torch_dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
        return cls(torch_dist.get_rank(), world_size)

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world_size > 1

    def average_gradients(self, params) -> None:
        if not self.active:
            return
        grads = [p.grad for p in params if p.grad is not None]
        if not grads:
            return
        flat = torch.cat([g.reshape(-1) for g in grads])
        torch_dist.all_reduce(flat)
        flat /= self.world_size
        offset = 0
        for g in grads:
            g.copy_(flat[offset:offset + g.numel()].view_as(g))
            offset += g.numel()

    def sum(self, x: torch.Tensor) -> torch.Tensor:
        if self.active:
            x = x.clone()
            torch_dist.all_reduce(x)
        return x

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        return self.sum(x.detach().reshape(1)) / self.world_size if self.active else x

    def update_norm(self, norm, observations: torch.Tensor) -> None:
        """Merge every rank's observations into the shared running statistics (identical on all ranks)."""
        if not self.active:
            norm.update(observations)
            return
        gathered = [torch.empty_like(observations) for _ in range(self.world_size)]
        torch_dist.all_gather(gathered, observations.detach().contiguous())
        norm.update(torch.cat(gathered))

    def close(self) -> None:
        if self.active and torch_dist.is_initialized():
            torch_dist.destroy_process_group()
