"""The fields' queries through ``torch.compile``: one fused kernel per query instead of ~100 small
tensor operations (a grid read is a dozen broadcast operations over (N, levels, 8) tensors, each a
pass over memory in eager mode).

Compiled: the SDF (forward, and its first derivatives: the locating pass, stage 2's normals,
evaluation) and the material (forward and backward). Not compiled: the SDF with its gradient's
graph (``create_graph``, the eikonal and shading terms of stage 1): ``torch.compile`` has no double
backward. Where compiling fails (no C++ compiler, an unsupported device), the queries run eagerly
for the rest of the process and a one-line warning says why.
"""
from __future__ import annotations

import sys
from typing import Callable

import torch
from torch import Tensor


class CompiledQueries:
    """``sdf(x)`` and ``material(x)`` compiled with dynamic batch sizes; eager after a failure."""

    def __init__(self, sdf: Callable[[Tensor], Tensor], sdf_grad: Callable[[Tensor], tuple[Tensor, Tensor]] | None,
                 material: Callable[[Tensor], tuple[Tensor, Tensor]]):
        self._eager = {"sdf": sdf, "sdf_grad": sdf_grad, "material": material}
        self._compiled = {k: torch.compile(f, dynamic=True) for k, f in self._eager.items() if f is not None}
        self.failed: str | None = None

    def _call(self, name: str, x: Tensor):
        if self.failed is None and x.shape[0] > 1:
            try:
                # a view (a reshape of the samples along rays) would be guarded by its base's shape: one
                # graph per base layout; a copy is one more pass over (N, 3) floats
                return self._compiled[name](x if x._base is None else x.clone())
            except Exception as e:  # the compiler, not the query: the eager call below is the same maths
                self.failed = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"[:200]
                print(f"warning: compiled field queries unavailable, running eagerly ({self.failed})", file=sys.stderr)
        return self._eager[name](x)

    def sdf(self, x: Tensor) -> Tensor:
        return self._call("sdf", x)

    def sdf_grad(self, x: Tensor) -> tuple[Tensor, Tensor]:
        return self._call("sdf_grad", x)

    def material(self, x: Tensor) -> tuple[Tensor, Tensor]:
        return self._call("material", x)


COMPILE_MIN_SECONDS = 120.0
COMPILE_MIN_ITERS = 1000
"""Below these a training run would spend a large share of itself compiling (~30 s on first use)."""


def compile_training(choice: str, iters: int, time_budget: float) -> bool:
    """``--compile`` on, off, or (auto) on for a run long enough to repay the compiling: ``iters``
    steps, or ``time_budget`` seconds where iters is 0."""
    if choice != "auto":
        return choice == "on"
    return iters >= COMPILE_MIN_ITERS if iters else time_budget >= COMPILE_MIN_SECONDS
