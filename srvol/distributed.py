"""Data-parallel training: each rank renders its share of every step's rays.

Launched by ``torchrun --standalone --nproc_per_node N -m srvol train SCENE --out RUN --distributed``
(one machine; across machines torchrun's --nnodes/--rdzv-endpoint). Every rank
draws the same step (pixels, PSF offsets, random eikonal points: one shared generator) and keeps
its contiguous share of it (:meth:`Shard.span`). Each loss term is a sum over the rank's share
divided by the count over all ranks (:meth:`Shard.total`), so the gradients summed over the ranks
(:meth:`Shard.sum_gradients`) are those of one process stepping on the whole batch; the random
offsets along the rays are rows of one whole-batch draw (:class:`srvol.render.RayRows`). Rank 0's
clock decides when the time budget ends and when stage 2 starts (:meth:`Shard.agree`), and rank 0
alone writes the log, checkpoints and model.

Backends: gloo on the CPU, nccl on CUDA. The run folder must be one folder all ranks see (one
machine, or a shared file system): a resume or a rollback reads rank 0's checkpoint on every rank.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import torch
from torch import Tensor

from srvol.errors import SrvolError


@dataclass(frozen=True)
class Shard:
    """This process's place among ``world`` data-parallel ranks (world 1: a plain run)."""

    rank: int = 0
    world: int = 1

    @property
    def is_main(self) -> bool:
        """Rank 0: the one that prints, logs and writes checkpoints."""
        return self.rank == 0

    def span(self, n: int) -> tuple[int, int]:
        """This rank's contiguous share [lo, hi) of n items (the first n % world ranks get one more)."""
        base, extra = divmod(n, self.world)
        lo = self.rank * base + min(self.rank, extra)
        return lo, lo + base + (self.rank < extra)

    def total(self, *values: float) -> tuple[float, ...]:
        """The sums over all ranks of per-rank numbers (counts for the loss's denominators, squared
        errors for the log), in one all-reduce."""
        if self.world == 1:
            return tuple(float(v) for v in values)
        t = torch.tensor(values, dtype=torch.float64, device=_device())
        torch.distributed.all_reduce(t)
        return tuple(t.tolist())

    def sum_gradients(self, params: list[Tensor]) -> None:
        """Sum every parameter's gradient over the ranks (one flat all-reduce); a parameter no rank
        reached keeps no gradient, one some ranks reached gets zeros where others had none."""
        if self.world == 1 or not params:
            return
        reached = torch.tensor([p.grad is not None for p in params], dtype=torch.float32, device=_device())
        torch.distributed.all_reduce(reached, op=torch.distributed.ReduceOp.MAX)
        params = [p for p, r in zip(params, reached.tolist()) if r > 0]
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
        flat = torch.cat([g.reshape(-1) for g in grads])
        torch.distributed.all_reduce(flat)
        at = 0
        for p, g in zip(params, grads):
            p.grad = flat[at:at + g.numel()].view_as(g).clone()
            at += g.numel()

    def agree(self, *values: float) -> tuple[float, ...]:
        """Rank 0's ``values`` on every rank (its clock: when the budget ends, when stage 2 starts)."""
        if self.world == 1:
            return values
        t = torch.tensor(values, dtype=torch.float64, device=_device())
        torch.distributed.broadcast(t, src=0)
        return tuple(t.tolist())

    def broadcast(self, t: Tensor) -> Tensor:
        """Rank 0's tensor ``t`` on every rank (same shape and dtype everywhere), on ``t``'s device."""
        if self.world == 1:
            return t
        out = t.detach().to(_device()).clone()
        torch.distributed.broadcast(out, src=0)
        return out.to(t.device)

    def gather_span(self, values: Tensor, lo: int, n: int) -> Tensor:
        """(n,) every rank's ``values``, each at its place ``lo`` in the whole (this rank's share of
        per-group numbers, e.g. its groups' errors), on ``values``' device."""
        if self.world == 1:
            return values
        whole = torch.zeros(n, dtype=torch.float64, device=_device())
        whole[lo:lo + len(values)] = values.detach().to(whole.device, torch.float64)
        torch.distributed.all_reduce(whole)
        return whole.to(values.device, values.dtype)

    def all_true(self, flag: bool) -> bool:
        """Whether ``flag`` holds on every rank (a finite loss: one rank's NaN rolls all ranks back)."""
        if self.world == 1:
            return flag
        t = torch.tensor([1.0 if flag else 0.0], device=_device())
        torch.distributed.all_reduce(t, op=torch.distributed.ReduceOp.MIN)
        return bool(t.item() > 0)

    def barrier(self) -> None:
        if self.world > 1:
            torch.distributed.barrier()


SINGLE = Shard()
"""A plain, one-process run."""


def _device() -> torch.device:
    """Where collective tensors live: the rank's GPU under nccl, else the CPU."""
    if torch.distributed.get_backend() == "nccl":
        return torch.device("cuda", torch.cuda.current_device())
    return torch.device("cpu")


def start(device: str) -> Shard:
    """Join the process group torchrun set up (RANK, WORLD_SIZE, MASTER_ADDR in the environment):
    gloo on the CPU, nccl on CUDA, each rank on its own GPU (LOCAL_RANK)."""
    if "RANK" not in os.environ or "WORLD_SIZE" not in os.environ:
        raise SrvolError("--distributed: start with torchrun, e.g. "
                         "`torchrun --standalone --nproc_per_node 2 -m srvol train SCENE --out RUN --distributed`")
    backend = "nccl" if device == "cuda" else "gloo"
    if device == "cuda":
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", 0)))
    if not torch.distributed.is_initialized():
        torch.distributed.init_process_group(backend)
    return Shard(rank=torch.distributed.get_rank(), world=torch.distributed.get_world_size())


def stop() -> None:
    if torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()
