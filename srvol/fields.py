"""Neural fields: the signed distance d(x) and the BRDF parameters at x.

Two families with one interface (:class:`SceneFields`):

* ``paper`` -- the paper's MLPs: SDF 5x512 with a skip at layer 4, positional
  encoding with 6 frequencies, geometric (sphere) initialisation, Softplus;
  albedo MLP 4x512 with 12 frequencies; specular MLP 3x256 with 6 frequencies.
* ``grid`` -- CPU-first: the SDF is a sphere plus a small MLP on multi-resolution
  dense feature grids (smoothstep interpolation, so normals are continuous and
  double backward works); the material is a small MLP on a multi-resolution
  hash grid, the specular head reading only the coarse levels. Their heads use
  GELU(100 x) / 100 (:class:`SharpGELU`), the shape of the paper's Softplus(100)
  at a quarter of the cost on a CPU.

Output decoding (sigmoid ranges, the alpha floor) lives here and only here:
:meth:`SceneFields.material` returns a :class:`~srvol.types.SurfaceMaterial`.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn as nn
from torch import Tensor

from srvol.types import ALPHA_MIN, SurfaceMaterial

BETA_FLOOR = 1e-4
BETA_INIT = 0.1
"""VolSDF's beta at the start of training (DESIGN.md section 3)."""


@dataclass(frozen=True)
class FieldConfig:
    """Architecture of the fields (saved in config.json; the ``auto`` preset derives it).

    kind: "grid" or "paper".
    sdf_levels: dense grid resolutions for the SDF (grid kind).
    sdf_channels: feature channels per SDF grid level.
    sdf_hidden: hidden width of the SDF head (grid) / of the SDF MLP (paper).
    mat_levels, mat_min_res, mat_max_res, mat_table_log2, mat_channels: the material hash grid.
    spec_levels: how many coarse material levels the specular head reads.
    mat_hidden: hidden width of the material heads.
    init_radius: radius of the initial sphere.
    activation: of the grid heads, "gelu" (:class:`SharpGELU`) or "softplus" (the paper's
        Softplus(beta=100); runs saved before the choice existed read as "softplus").
    paper_*: the paper's MLP sizes.
    """

    kind: str = "grid"
    sdf_levels: tuple[int, ...] = (16, 32, 64)
    sdf_channels: int = 4
    sdf_hidden: int = 64
    mat_levels: int = 10
    mat_min_res: int = 16
    mat_max_res: int = 512
    mat_table_log2: int = 17
    mat_channels: int = 2
    spec_levels: int = 4
    mat_hidden: int = 64
    init_radius: float = 0.5
    activation: str = "gelu"
    paper_sdf_layers: int = 5
    paper_sdf_width: int = 512
    paper_sdf_skip: int = 4
    paper_sdf_freqs: int = 6
    paper_albedo_layers: int = 4
    paper_albedo_width: int = 512
    paper_albedo_freqs: int = 12
    paper_spec_layers: int = 3
    paper_spec_width: int = 256
    paper_spec_freqs: int = 6

    def to_json(self) -> dict:
        d = asdict(self)
        d["sdf_levels"] = list(self.sdf_levels)
        return d

    @staticmethod
    def from_json(d: dict) -> "FieldConfig":
        d = dict(d)
        d["sdf_levels"] = tuple(d.get("sdf_levels", FieldConfig.sdf_levels))
        d.setdefault("activation", "softplus")  # saved before the choice existed
        known = FieldConfig.__dataclass_fields__
        return FieldConfig(**{k: v for k, v in d.items() if k in known})

    def parameter_summary(self) -> str:
        if self.kind == "paper":
            return (f"paper MLPs: SDF {self.paper_sdf_layers}x{self.paper_sdf_width} (PE {self.paper_sdf_freqs}), "
                    f"albedo {self.paper_albedo_layers}x{self.paper_albedo_width} (PE {self.paper_albedo_freqs}), "
                    f"specular {self.paper_spec_layers}x{self.paper_spec_width} (PE {self.paper_spec_freqs})")
        return (f"SDF grids {'/'.join(map(str, self.sdf_levels))}^3 x{self.sdf_channels} + {self.sdf_hidden}-wide head; "
                f"material hash grid {self.mat_levels} levels {self.mat_min_res}..{self.mat_max_res} "
                f"(2^{self.mat_table_log2} x{self.mat_channels}); heads {self.activation}")


# ----------------------------------------------------------------------------- encodings

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


def _cell_corners(x: Tensor, res: int, smooth: bool) -> tuple[Tensor, Tensor]:
    """Integer corner coordinates (N, 8, 3) of the cell around each point of a res^3 grid over
    [-1, 1]^3 (grid points at the ends), and the interpolation weights (N, 8).

    ``smooth``: smoothstep weights (C1 across cells: continuous normals) instead of trilinear.
    """
    u = ((x.clamp(-1.0, 1.0) + 1.0) * 0.5 * (res - 1)).clamp(0.0, res - 1 - 1e-4)
    # a NaN point (a diverged step) reads corner 0 with NaN weights: the loss turns NaN and training
    # rolls back, instead of indexing out of the table
    i0 = torch.nan_to_num(u.detach().floor(), nan=0.0)
    f = u - i0
    if smooth:
        f = f * f * (3.0 - 2.0 * f)
    corners = _CORNERS.to(x.device)
    c = i0.long()[:, None, :] + corners[None]  # (N, 8, 3)
    # per-axis factors (N, 3, 2) = [1 - f, f]; a corner's weight is the product of its three
    fx = torch.stack([1.0 - f, f], dim=-1)
    w = fx[:, 0, corners[:, 0]] * fx[:, 1, corners[:, 1]] * fx[:, 2, corners[:, 2]]
    return c, w


class DenseGrids(nn.Module):
    """Multi-resolution dense feature grids over [-1, 1]^3 with smoothstep interpolation.

    All levels live in one table and are read with one gather (not grid_sample), so
    that second derivatives exist: the SDF's normal is an autograd gradient, and the
    eikonal and shading losses differentiate through it.

    Smoothstep rather than trilinear, though only trilinear reproduces a plane exactly: on the stool
    scene (flat seat, thin legs; 300 s, 1 thread, the thin-parts flags) trilinear grids gave 34.85 dB
    HR PSNR and 13.8 deg normal MAE against 35.92 dB and 13.2 deg with smoothstep.
    """

    def __init__(self, levels: tuple[int, ...], channels: int, init_std: float = 1e-4):
        super().__init__()
        self.levels = tuple(levels)
        self.offsets = [0]
        for r in self.levels:
            self.offsets.append(self.offsets[-1] + r ** 3)
        self.channels = channels
        self.table = nn.Parameter(torch.randn(self.offsets[-1], channels) * init_std)

    @property
    def out_dim(self) -> int:
        return len(self.levels) * self.channels

    def forward(self, x: Tensor) -> Tensor:
        idx, ws = [], []
        for lvl, res in enumerate(self.levels):
            c, w = _cell_corners(x, res, smooth=True)
            idx.append((c[..., 0] * res + c[..., 1]) * res + c[..., 2] + self.offsets[lvl])
            ws.append(w)
        feats = _gather_rows(self.table, torch.stack(idx, 1))  # (N, L, 8, C)
        return (torch.stack(ws, 1)[..., None] * feats).sum(2).flatten(1)


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
        w = torch.stack(w_all, 1)  # (N, L, 8)
        feats = _gather_rows(self.table, idx)  # (N, L, 8, C)
        return (w[..., None] * feats).sum(2).flatten(1)


# ----------------------------------------------------------------------------- fields

class SceneFields(nn.Module):
    """SDF + material fields, VolSDF's beta, and (when the scene does not give it) the light intensity."""

    def __init__(self, cfg: FieldConfig, learn_intensity: bool, intensity_init: float = 10.0):
        super().__init__()
        self.cfg = cfg
        self.log_beta = nn.Parameter(torch.tensor(math.log(BETA_INIT)))
        self.log_intensity = nn.Parameter(torch.full((3,), math.log(intensity_init)), requires_grad=learn_intensity)
        if cfg.kind == "paper":
            self.sdf_net = PaperSDF(cfg)
            self.albedo_net = _mlp(3 + 6 * cfg.paper_albedo_freqs, cfg.paper_albedo_width, 3, cfg.paper_albedo_layers)
            self.spec_net = _mlp(3 + 6 * cfg.paper_spec_freqs, cfg.paper_spec_width, 2, cfg.paper_spec_layers)
        elif cfg.kind == "grid":
            self.sdf_net = GridSDF(cfg)
            self.mat_grid = HashGrids(cfg.mat_levels, cfg.mat_min_res, cfg.mat_max_res, cfg.mat_table_log2,
                                      cfg.mat_channels)
            self.albedo_net = _mlp(self.mat_grid.out_dim, cfg.mat_hidden, 3, 2, cfg.activation)
            self.spec_dim = min(cfg.spec_levels, cfg.mat_levels) * cfg.mat_channels
            self.spec_net = _mlp(self.spec_dim, cfg.mat_hidden // 2, 2, 2, cfg.activation)
        else:
            raise ValueError(f"unknown field kind {cfg.kind!r}")
        # Start grey (albedo ~0.5), F0 ~0.04, alpha ~0.25.
        with torch.no_grad():
            self.spec_net[-1].bias.copy_(torch.tensor([math.log(0.04 / 0.96), 0.0]))

    # -- geometry
    @property
    def beta(self) -> Tensor:
        return self.log_beta.exp() + BETA_FLOOR

    @torch.no_grad()
    def cap_beta(self, cap: float) -> None:
        """Bound beta above by ``cap`` (a schedule's step; never below the floor)."""
        self.log_beta.clamp_(max=math.log(max(cap - BETA_FLOOR, 1e-12)))

    @property
    def intensity(self) -> Tensor:
        return self.log_intensity.exp()

    def geometry_parameters(self) -> list[nn.Parameter]:
        return list(self.sdf_net.parameters()) + [self.log_beta]

    def finest_sdf_cell(self) -> float | None:
        """Side of the SDF's finest grid cell over [-1, 1]^3 (scene units), None for MLP fields:
        no shape detail much below it exists in the model (export sizes its marching cubes by it)."""
        return 2.0 / max(self.cfg.sdf_levels) if self.cfg.kind == "grid" else None

    def sdf(self, x: Tensor) -> Tensor:
        """(N, 3) -> (N,) signed distance, negative inside."""
        return self.sdf_net(x)

    def sdf_and_gradient(self, x: Tensor, create_graph: bool) -> tuple[Tensor, Tensor]:
        """SDF and its spatial gradient (not normalised). ``create_graph`` for losses on the gradient."""
        with torch.enable_grad():
            if not x.requires_grad:
                x = x.detach().requires_grad_(True)
            d = self.sdf_net(x)
            (g,) = torch.autograd.grad(d, x, torch.ones_like(d), create_graph=create_graph)
        return d, g

    # -- material
    def material(self, x: Tensor) -> SurfaceMaterial:
        """Decoded BRDF parameters: albedo = sigmoid, F0 = sigmoid, alpha in [ALPHA_MIN, 1]."""
        if self.cfg.kind == "paper":
            a = self.albedo_net(positional_encoding(x, self.cfg.paper_albedo_freqs))
            s = self.spec_net(positional_encoding(x, self.cfg.paper_spec_freqs))
        else:
            feats = self.mat_grid(x)
            a = self.albedo_net(feats)
            s = self.spec_net(feats[:, : self.spec_dim])
        albedo = torch.sigmoid(a)
        specular = torch.sigmoid(s[:, :1])
        alpha = ALPHA_MIN + (1.0 - ALPHA_MIN) * torch.sigmoid(s[:, 1:2] - 1.1)
        return SurfaceMaterial(albedo=albedo, specular=specular, alpha=alpha)

    def material_groups(self) -> tuple[list[nn.Parameter], list[nn.Parameter], list[nn.Parameter]]:
        """(albedo MLP params, specular MLP params, feature tables)."""
        tables = [self.mat_grid.table] if self.cfg.kind == "grid" else []
        return list(self.albedo_net.parameters()), list(self.spec_net.parameters()), tables


class SharpGELU(nn.Module):
    """GELU(100 x) / 100: a ReLU rounded over ~0.01, like Softplus(beta=100), and as smooth
    (C-infinity: continuous normals, and the eikonal term's double backward exists).

    Measured on 2 CPU cores: 0.3 ms for GELU vs 1.1 ms for Softplus on 1.4 M activations;
    Softplus was 22% of a stage-1 and 36% of a stage-2 step of auto on the default scene, and
    with this activation a 600 s auto run takes 29% more steps (6286 vs 4871 with --sr
    gaussian, 5485 vs 4384 with none) at the same HR PSNR (39.45 vs 39.40, 38.96 vs 38.93 dB on test
    views 040-042).
    """

    def forward(self, x: Tensor) -> Tensor:
        return torch.nn.functional.gelu(x * 100.0) * 0.01


def _activation(name: str) -> nn.Module:
    if name == "gelu":
        return SharpGELU()
    if name == "softplus":
        return nn.Softplus(beta=100)
    raise ValueError(f"unknown activation {name!r} (gelu or softplus)")


def _mlp(d_in: int, width: int, d_out: int, layers: int, activation: str = "softplus") -> nn.Sequential:
    """``layers`` linear layers (layers - 1 hidden), ``activation`` between them."""
    mods: list[nn.Module] = []
    d = d_in
    for _ in range(layers - 1):
        mods += [nn.Linear(d, width), _activation(activation)]
        d = width
    mods.append(nn.Linear(d, d_out))
    return nn.Sequential(*mods)


class GridSDF(nn.Module):
    """d(x) = |x| - r0 + head(grids(x)): a sphere plus a learned residual (zero at init)."""

    def __init__(self, cfg: FieldConfig):
        super().__init__()
        self.r0 = cfg.init_radius
        self.grids = DenseGrids(cfg.sdf_levels, cfg.sdf_channels)
        self.head = _mlp(self.grids.out_dim + 3, cfg.sdf_hidden, 1, 3, cfg.activation)
        with torch.no_grad():
            self.head[-1].weight.mul_(0.01)
            self.head[-1].bias.zero_()

    def forward(self, x: Tensor) -> Tensor:
        base = x.norm(dim=-1) - self.r0
        return base + self.head(torch.cat([x, self.grids(x)], dim=-1))[:, 0]


class PaperSDF(nn.Module):
    """The paper's SDF MLP: ``paper_sdf_layers`` hidden layers of ``paper_sdf_width``, the input
    concatenated again before hidden layer ``paper_sdf_skip`` (IDR's layout), Softplus(100),
    and IDR's geometric initialisation so that d(x) starts as |x| - r0."""

    def __init__(self, cfg: FieldConfig):
        super().__init__()
        self.freqs = cfg.paper_sdf_freqs
        d_in = 3 + 6 * cfg.paper_sdf_freqs
        W = cfg.paper_sdf_width
        self.skip = cfg.paper_sdf_skip
        dims = [d_in] + [W] * cfg.paper_sdf_layers + [1]
        self.layers = nn.ModuleList()
        n = len(dims) - 1
        for i in range(n):
            in_dim = dims[i]
            out_dim = dims[i + 1] - d_in if i + 1 == self.skip else dims[i + 1]
            lin = nn.Linear(in_dim, out_dim)
            # geometric initialisation (Atzmon & Lipman 2020), as in IDR / VolSDF
            if i == n - 1:
                nn.init.normal_(lin.weight, mean=math.sqrt(math.pi) / math.sqrt(in_dim), std=1e-4)
                nn.init.constant_(lin.bias, -cfg.init_radius)
            else:
                nn.init.constant_(lin.bias, 0.0)
                nn.init.normal_(lin.weight, 0.0, math.sqrt(2) / math.sqrt(out_dim))
                if i == 0:
                    nn.init.constant_(lin.weight[:, 3:], 0.0)  # encoding starts silent
                elif i == self.skip:
                    nn.init.constant_(lin.weight[:, -(d_in - 3):], 0.0)
            self.layers.append(nn.utils.parametrizations.weight_norm(lin))
        self.act = nn.Softplus(beta=100)

    def forward(self, x: Tensor) -> Tensor:
        inp = positional_encoding(x, self.freqs)
        h = inp
        for i, lin in enumerate(self.layers):
            if i == self.skip:
                h = torch.cat([h, inp], dim=-1) / math.sqrt(2)
            h = lin(h)
            if i < len(self.layers) - 1:
                h = self.act(h)
        return h[:, 0]
