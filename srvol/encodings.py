"""Input encodings of the fields: positional encoding (the paper's MLPs), multi-resolution dense
grids (the grid SDF; second derivatives exist, for normals inside losses) and multi-resolution hash
grids (the material). All grid levels are read with one gather per call."""
from __future__ import annotations

import math

import torch
import torch.nn as nn
from torch import Tensor


def positional_encoding(x: Tensor, n_freqs: int) -> Tensor:
    """[x, sin(2^k pi x), cos(2^k pi x)] for k < n_freqs: (N, 3) -> (N, 3 + 6 n_freqs)."""
    if n_freqs == 0:
        return x
    freqs = (2.0 ** torch.arange(n_freqs, device=x.device, dtype=x.dtype)) * math.pi
    xf = x[:, None, :] * freqs[:, None]
    return torch.cat([x, torch.sin(xf).flatten(1), torch.cos(xf).flatten(1)], dim=-1)


def _gather_rows(table: Tensor, idx: Tensor) -> Tensor:
    """table[idx] via index_select: its backward is index_add (measured ~5x faster on CPU than
    embedding's sorting backward) and is itself differentiable (double backward for normals)."""
    return torch.index_select(table, 0, idx.reshape(-1)).reshape(*idx.shape, table.shape[1])


_CORNERS = torch.tensor([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)])  # (8, 3)


def _grid_coords(x: Tensor, res: int) -> Tensor:
    """Continuous coordinates (N, 3) in [0, res - 1) of points of [-1, 1]^3 on a res^3 grid (nodes at the ends)."""
    return ((x.clamp(-1.0, 1.0) + 1.0) * 0.5 * (res - 1)).clamp(0.0, res - 1 - 1e-4)


def _node_weights(fx: Tensor, k: Tensor) -> Tensor:
    """(N, K) weights of K nodes from per-axis factors fx (N, 3, M): node j's weight is the product
    of fx[:, a, k[j, a]] over the three axes (k: (K, 3) indices into the M factors)."""
    return fx[:, 0, k[:, 0]] * fx[:, 1, k[:, 1]] * fx[:, 2, k[:, 2]]


def _cell_corners(x: Tensor, res: int, smooth: bool) -> tuple[Tensor, Tensor]:
    """Integer corner coordinates (N, 8, 3) of the cell around each point of a res^3 grid over
    [-1, 1]^3 (grid points at the ends), and the interpolation weights (N, 8).

    ``smooth``: smoothstep weights (C1 across cells: continuous normals) instead of trilinear.
    """
    u = _grid_coords(x, res)
    # a NaN point (a diverged step) reads corner 0 with NaN weights: the loss turns NaN and training
    # rolls back, instead of indexing out of the table
    i0 = torch.nan_to_num(u.detach().floor(), nan=0.0)
    f = u - i0
    if smooth:
        f = f * f * (3.0 - 2.0 * f)
    corners = _CORNERS.to(x.device)
    c = i0.long()[:, None, :] + corners[None]  # (N, 8, 3)
    # per-axis factors (N, 3, 2) = [1 - f, f]
    return c, _node_weights(torch.stack([1.0 - f, f], dim=-1), corners)


def _smoothstep_cell(x: Tensor, res: int) -> tuple[Tensor, Tensor]:
    """Flat indices (N, 8) into a res^3 table of the corners of the cell around each point, and
    the corners' smoothstep weights with their x-derivatives (N, 4, 8): [w, dw/dx0, dw/dx1, dw/dx2],
    by hand (what autograd would give, without a second graph)."""
    u = _grid_coords(x, res)
    i0 = torch.nan_to_num(u.detach().floor(), nan=0.0)  # NaN: as in _cell_corners
    f = u - i0
    s = f * f * (3.0 - 2.0 * f)
    ds = 6.0 * f * (1.0 - f) * _clamp_slope(x, u, res)  # d s / d x
    corners = _CORNERS.to(x.device)
    c = i0.long()[:, None, :] + corners[None]
    idx = (c[..., 0] * res + c[..., 1]) * res + c[..., 2]
    fx, dfx = torch.stack([1.0 - s, s], dim=-1), torch.stack([-ds, ds], dim=-1)  # (N, 3, 2)
    return idx, _with_derivatives(fx, dfx, lambda f: _node_weights(f, corners))


def _weighted_nodes(w: Tensor, feats: Tensor) -> Tensor:
    """sum_k w[..., k] feats[..., k, :]: (..., K) and (..., K, C) -> (..., C). Eagerly, a batched
    product for the B-spline's 27 nodes (~2x a query's speed; slower for 8); compiled, a product and
    a sum, which the compiler fuses with the gather (measured: 48 vs 61 ms for 20k B-spline queries)."""
    if w.shape[-1] > 8 and not torch.compiler.is_compiling():
        return torch.einsum("...k,...kc->...c", w, feats)
    return (w[..., None] * feats).sum(-2)


def _outer3(per_axis: Tensor, combine) -> Tensor:
    """(N, 3, M) per-axis values -> (N, M^3) over the nodes of a cell, first axis slowest, each
    ``combine(a, b, c)`` of its three axes' values, by broadcasting."""
    return combine(per_axis[:, 0, :, None, None], per_axis[:, 1, None, :, None], per_axis[:, 2, None, None, :]).flatten(1)


def _bspline_nodes(x: Tensor, res: int) -> tuple[Tensor, Tensor]:
    """Flat indices (N, 27) into a res^3 table of the 27 grid nodes around each point of [-1, 1]^3,
    and their uniform quadratic B-spline weights (N, 27): C1 across cells (continuous normals) and,
    unlike smoothstep, exact on linear functions (a tilted plane's gradient is constant, not terraced).
    Built by broadcasting per-axis values, not by indexing them: for 27 nodes its backward (a sum,
    not a scatter) made a query with its x-gradient ~1.5x as fast on CPU."""
    idx, fx, _ = _bspline_factors(x, res)
    return idx, _outer3(fx, lambda a, b, c: a * b * c)


def _bspline_factors(x: Tensor, res: int) -> tuple[Tensor, Tensor, Tensor]:
    """Flat indices (N, 27) of the B-spline's nodes, its per-axis weights (N, 3, 3) and their
    x-derivatives (N, 3, 3)."""
    u = _grid_coords(x, res)
    j0 = torch.nan_to_num((u.detach() + 0.5).floor(), nan=0.0)  # the nearest node (NaN: as in _cell_corners)
    t = u - j0 + 0.5
    fx = torch.stack([0.5 * (1.0 - t) ** 2, 0.75 - (t - 0.5) ** 2, 0.5 * t * t], dim=-1)  # (N, 3, 3)
    dt = _clamp_slope(x, u, res)
    dfx = torch.stack([(t - 1.0) * dt, (1.0 - 2.0 * t) * dt, t * dt], dim=-1)
    j0 = j0.long()
    nodes = torch.stack([j0 - 1, j0, j0 + 1], dim=-1).clamp(0, res - 1)  # (N, 3, 3)
    return _outer3(nodes, lambda a, b, c: (a * res + b) * res + c), fx, dfx


def _clamp_slope(x: Tensor, u: Tensor, res: int) -> Tensor:
    """du/dx (N, 3) of :func:`_grid_coords`: half the grid's cells per scene unit where its clamps
    pass gradients, 0 where they hold."""
    inside = (x >= -1.0) & (x <= 1.0) & (u >= 0.0) & (u <= res - 1 - 1e-4)
    return (0.5 * (res - 1)) * inside


def _with_derivatives(fx: Tensor, dfx: Tensor, nodes_weights) -> Tensor:
    """(N, 4, K): a cell's node weights and their derivatives along x0, x1, x2 -- the weight with
    one axis's factors differentiated, the other two as they are (``nodes_weights``: per-axis
    factors (N, 3, M) -> (N, K))."""
    weights = [nodes_weights(fx)]
    for a in range(3):
        fa = fx.clone()
        fa[:, a] = dfx[:, a]
        weights.append(nodes_weights(fa))
    return torch.stack(weights, 1)


SDF_INTERPOLATIONS = ("smoothstep", "bspline")


class DenseGrids(nn.Module):
    """Multi-resolution dense feature grids over [-1, 1]^3, smoothstep (8 nodes) or quadratic
    B-spline (27 nodes) interpolation.

    All levels live in one table and are read with one gather (not grid_sample), so
    that second derivatives exist: the SDF's normal is an autograd gradient, and the
    eikonal and shading losses differentiate through it.

    Smoothstep rather than trilinear, though trilinear reproduces a plane exactly: on the stool
    scene (flat seat, thin legs; 300 s, 1 thread, the thin-parts flags) trilinear grids gave 34.85 dB
    HR PSNR and 13.8 deg normal MAE against 35.92 dB and 13.2 deg with smoothstep. The B-spline has
    both (C1 and exact on planes) at ~2x the cost of a training query: it wins where the surface
    travels far from the initial sphere (stool, airplane: +2.3 and +2.9 dB in 600 s) and loses on
    near-spheres (shiny -0.64, glossy -1.23; bench/results/suite_tuning.md), so ``auto`` picks it from
    the masks' solidity (srvol/presets.py) and smoothstep is the default otherwise.
    """

    def __init__(self, levels: tuple[int, ...], channels: int, init_std: float = 1e-4,
                 interpolation: str = "smoothstep"):
        super().__init__()
        if interpolation not in SDF_INTERPOLATIONS:
            raise ValueError(f"unknown SDF grid interpolation {interpolation!r} ({', '.join(SDF_INTERPOLATIONS)})")
        self.interpolation = interpolation
        self.levels = tuple(levels)
        self.offsets = [0]
        for r in self.levels:
            self.offsets.append(self.offsets[-1] + r ** 3)
        self.channels = channels
        self.table = nn.Parameter(torch.randn(self.offsets[-1], channels) * init_std)
        self.register_buffer("level_weights", torch.ones(len(self.levels)), persistent=False)

    @property
    def out_dim(self) -> int:
        return len(self.levels) * self.channels

    def with_jacobian(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Features (N, F) and their x-derivatives (N, 3, F), as plain
        differentiable operations: their gradients need no double backward, so the normal's path
        can be compiled (:mod:`srvol.compiled`). Equal to ``forward`` and its autograd Jacobian."""
        idx, ws = [], []
        for lvl, res in enumerate(self.levels):
            if self.interpolation == "bspline":
                i, fx, dfx = _bspline_factors(x, res)
                w = _with_derivatives(fx, dfx, lambda f: _outer3(f, lambda a, b, c: a * b * c))
            else:
                i, w = _smoothstep_cell(x, res)
            idx.append(i + self.offsets[lvl])
            ws.append(w)
        feats = _gather_rows(self.table, torch.stack(idx, 1))  # (N, L, K, C)
        w = torch.stack(ws, 2) * self.level_weights[:, None]  # (N, 4, L, K)
        out = _weighted_nodes(w, feats[:, None].expand(-1, 4, -1, -1, -1))  # (N, 4, L, C)
        return out[:, 0].flatten(1), out[:, 1:].flatten(2)

    def forward(self, x: Tensor) -> Tensor:
        idx, ws = [], []
        for lvl, res in enumerate(self.levels):
            if self.interpolation == "bspline":
                i, w = _bspline_nodes(x, res)
            else:
                c, w = _cell_corners(x, res, smooth=True)
                i = (c[..., 0] * res + c[..., 1]) * res + c[..., 2]
            idx.append(i + self.offsets[lvl])
            ws.append(w)
        feats = _gather_rows(self.table, torch.stack(idx, 1))  # (N, L, 8 or 27, C)
        w = torch.stack(ws, 1) * self.level_weights[:, None]
        return _weighted_nodes(w, feats).flatten(1)


_PRIMES = (1, 2654435761, 805459861)


class HashGrids(nn.Module):
    """Multi-resolution hash encoding (Mueller et al. 2022).

    Levels whose dense grid fits in the table are indexed densely (no collisions).
    All levels and corners are gathered in one embedding call. Dense table gradients
    with fused Adam measured ~4x faster on 2 CPU cores than sparse gradients with
    SparseAdam (the sparse gradient's coalescing sort dominates).
    First derivatives only (used for the material, which needs no normals).
    """

    def __init__(self, n_levels: int, min_res: int, max_res: int, table_log2: int, channels: int):
        super().__init__()
        growth = math.exp((math.log(max_res) - math.log(min_res)) / max(n_levels - 1, 1))
        self.resolutions = [int(math.floor(min_res * growth ** i)) for i in range(n_levels)]
        self.table_size = 1 << table_log2
        sizes = [min(r ** 3, self.table_size) for r in self.resolutions]
        offsets = [0]
        for s in sizes:
            offsets.append(offsets[-1] + s)
        self.offsets = offsets
        self.channels = channels
        self.table = nn.Parameter(torch.empty(offsets[-1], channels).uniform_(-1e-4, 1e-4))
        self.register_buffer("level_weights", torch.ones(n_levels), persistent=False)

    @property
    def out_dim(self) -> int:
        return len(self.resolutions) * self.channels

    def forward(self, x: Tensor, n_levels: int | None = None) -> Tensor:
        """(N, 3) in [-1, 1] -> (N, L * C) features of the first ``n_levels`` levels (all by default)."""
        idx_all, w_all = [], []
        for lvl, res in enumerate(self.resolutions[: n_levels or len(self.resolutions)]):
            c, w = _cell_corners(x, res, smooth=False)
            c = c.clamp(max=res - 1)
            if res ** 3 <= self.table_size:
                ii = (c[..., 0] * res + c[..., 1]) * res + c[..., 2]
            else:
                ii = ((c[..., 0] * _PRIMES[0]) ^ (c[..., 1] * _PRIMES[1]) ^ (c[..., 2] * _PRIMES[2])) % self.table_size
            idx_all.append(ii + self.offsets[lvl])
            w_all.append(w)
        idx = torch.stack(idx_all, 1)  # (N, L, 8)
        w = torch.stack(w_all, 1) * self.level_weights[: idx.shape[1], None]  # (N, L, 8)
        feats = _gather_rows(self.table, idx)  # (N, L, 8, C)
        return (w[..., None] * feats).sum(2).flatten(1)


def level_window(n_levels: int, always_on: int, share: float) -> Tensor:
    """Weights (n_levels,) of a coarse-to-fine schedule at ``share`` in [0, 1] of its span: the
    first ``always_on`` levels are on from the start, the rest come in one after another, each
    fading from 0 to 1 over its turn (Neuralangelo's progressive levels, made continuous)."""
    fixed = min(max(always_on, 0), n_levels)
    active = fixed + min(max(share, 0.0), 1.0) * (n_levels - fixed)
    return (active - torch.arange(n_levels, dtype=torch.float32)).clamp(0.0, 1.0)
