"""Stage 2 draws its pixels where the error is: an error map over the training views.

Once the geometry is frozen, a few flash highlights hold most of what is left to fit. On the tuning
scene glossy's finished model, the 4x4-pixel patches around 1 % of the in-mask pixels hold 89 % of
the squared error and 0.1 % of them hold 54 %. A step draws 5-7 patches uniformly, so it meets one
of those now and then, and when it does the step's loss and gradient jump: the logged PSNR of a
25-step window swung by 14 dB, and its median sat 6 dB above the PSNR of the whole image set,
because most windows miss the highlights altogether.

Here the patch centres are drawn with probability ``(1 - share) / N + share * e_c / sum(e)``: a
mixture of the uniform draw and a running estimate ``e_c`` of the error of the patches centred in
each cell of CELL x CELL LR pixels. Each pixel's terms are weighted by ``(1 / N) / p``, so the loss
and the logged PSNR estimate the same means as the uniform draw, with the variance of the
highlights taken out (and the uniform share bounds each weight by ``1 / (1 - share)``).
instant-ngp samples its training pixels by an error map in the same way.

The map starts from one render of every in-mask pixel (one ray at the pixel centre: 4-8 s on the
tuning scenes glossy and shiny, one thread): a cell takes the mean error of the patches centred in
it. Each step then writes the error it measured on its patches into their centres' cells. A map
measured at every other pixel in each direction (a quarter of the time), each pixel lent its measured
neighbour's error, reads a highlight on an unmeasured pixel as no error until a step draws it by the
uniform share: on shiny's finished model the 25-step window PSNR's 1st-99th percentiles span 5.9 dB
drawn by it, 3.1 by the full map (``bench.bench_error_map``; suite_tuning.md).
"""
from __future__ import annotations

import torch
from torch import Tensor

CELL = 4
"""Side of an error-map cell in LR pixels: one stage-2 lattice patch."""

UPDATE_RATE = 0.25
"""How far a cell's error moves to each measurement of a group centred in it. Writing the last
measurement in (rate 1) left glossy's and shiny's logged 25-step PSNR within 5.1 and 4.1 dB of its
running median; the groups centred in one cell differ, and one low draw hid the rest of the cell."""

STAGE2_IMPORTANCE = 0.5
"""auto's share of stage 2's draw that follows the map. On glossy's finished auto run
(``python -m bench.bench_error_map RUN``: 400 windows of 25 steps of 7 patches, drawn from the
model's own errors) a window's PSNR spans 29.30-32.77 dB at 0.5 and 29.00-32.63 at 0.8 (1st-99th
percentile; the whole set's 30.94), 22.83-41.47 drawn uniformly. A larger share buys nothing and
raises the bound on the uniform draws' weights, 1 / (1 - share)."""


class ErrorMap:
    """Per-cell error estimates of the in-mask pixels of a :class:`srvol.pixels.PixelBank`, and
    draws of in-mask pixels from them.

    ``cell_of`` (N,): the cell of each of ``bank.inside``'s N pixels; ``error`` (C,): the error of
    a group (a patch, or one pixel) centred in each cell, 1 until measured.
    """

    def __init__(self, bank, share: float, cell: int = CELL):
        if not 0.0 <= share < 1.0:
            raise ValueError(f"share {share}: must be in [0, 1)")
        self.share = share
        self.inside = bank.inside
        ij = bank.ij[self.inside].long()
        view = bank.view[self.inside]
        cols = (bank.sizes[:, 1] + cell - 1) // cell  # cells across each view
        rows = (bank.sizes[:, 0] + cell - 1) // cell
        first = torch.cumsum(torch.cat([torch.zeros(1, dtype=torch.long, device=cols.device), rows * cols]), 0)
        flat = first[view] + (ij[:, 1] // cell) * cols[view] + ij[:, 0] // cell
        cells, self.cell_of = torch.unique(flat, return_inverse=True)
        self.count = torch.bincount(self.cell_of, minlength=len(cells)).float()
        self.error = torch.ones(len(cells), device=self.inside.device)

    def __len__(self) -> int:
        return len(self.error)

    def probabilities(self) -> Tensor:
        """(N,) the probability of drawing each in-mask pixel (summing to 1)."""
        n = len(self.inside)
        total = float((self.error * self.count).sum())
        if self.share == 0.0 or not total > 0.0:
            return torch.full((n,), 1.0 / n, device=self.error.device)
        return (1.0 - self.share) / n + self.share * self.error[self.cell_of] / total

    def draw(self, n: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """``n`` in-mask pixels (indices into ``bank.inside``) and each one's importance weight
        ``(1 / N) / p``: weighted means over them estimate the uniform draw's."""
        p = self.probabilities()
        cdf = torch.cumsum(p, 0)
        u = torch.rand(n, generator=generator).to(cdf.device) * cdf[-1]
        idx = torch.searchsorted(cdf, u).clamp_max(len(p) - 1)
        return idx, (1.0 / len(p)) / p[idx]

    def update(self, idx: Tensor, group_error: Tensor) -> None:
        """Move the cells of groups centred at in-mask pixels ``idx`` UPDATE_RATE of the way to the
        error measured on them (one group is one of a cell's 16 centres: a running mean, not the last
        draw, stands for the cell)."""
        cells = self.cell_of[idx]
        measured = group_error.detach().to(self.error.dtype).clamp_min(0.0)
        self.error[cells] = (1.0 - UPDATE_RATE) * self.error[cells] + UPDATE_RATE * measured

    def fill(self, group_error: Tensor) -> None:
        """Each cell's error from a first measurement of every in-mask pixel's group (N,): the mean
        over the cell's pixels."""
        total = torch.zeros_like(self.error).index_add_(0, self.cell_of, group_error.to(self.error.dtype))
        self.error = (total / self.count).clamp_min(0.0)


def patch_sums(bank, pixel_values: Tensor, patch: int) -> Tensor:
    """(N,) for each in-mask pixel the sum of ``pixel_values`` (one per bank row, 0 off the mask)
    over the ``patch`` x ``patch`` patch a stage-2 draw centred there covers (:meth:`srvol.pixels.PixelBank.patch_origin`)."""
    v = bank.view[bank.inside]
    W = bank.sizes[v, 1]
    x0, y0 = bank.patch_origin(bank.inside, patch).long().unbind(-1)
    out = torch.zeros(len(v), dtype=pixel_values.dtype, device=pixel_values.device)
    for dx in range(patch):
        for dy in range(patch):
            out += pixel_values[bank.view_start[v] + (y0 + dy) * W + x0 + dx]
    return out
