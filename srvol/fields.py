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

from srvol.encodings import DenseGrids, HashGrids, level_window, positional_encoding
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
    sdf_interpolation: of the SDF grids, "smoothstep" or "bspline" (quadratic B-spline).
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
    sdf_interpolation: str = "smoothstep"
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
        d.setdefault("sdf_interpolation", "smoothstep")  # likewise
        known = FieldConfig.__dataclass_fields__
        return FieldConfig(**{k: v for k, v in d.items() if k in known})

    def parameter_summary(self) -> str:
        if self.kind == "paper":
            return (f"paper MLPs: SDF {self.paper_sdf_layers}x{self.paper_sdf_width} (PE {self.paper_sdf_freqs}), "
                    f"albedo {self.paper_albedo_layers}x{self.paper_albedo_width} (PE {self.paper_albedo_freqs}), "
                    f"specular {self.paper_spec_layers}x{self.paper_spec_width} (PE {self.paper_spec_freqs})")
        interp = "" if self.sdf_interpolation == "smoothstep" else f" ({self.sdf_interpolation})"
        return (f"SDF grids {'/'.join(map(str, self.sdf_levels))}^3 x{self.sdf_channels}{interp} + {self.sdf_hidden}-wide head; "
                f"material hash grid {self.mat_levels} levels {self.mat_min_res}..{self.mat_max_res} "
                f"(2^{self.mat_table_log2} x{self.mat_channels}); heads {self.activation}")


# ----------------------------------------------------------------------------- fields

class SceneFields(nn.Module):
    """SDF + material fields, VolSDF's beta, and (when the scene does not give it) the light intensity."""

    def __init__(self, cfg: FieldConfig, learn_intensity: bool, intensity_init: float = 10.0):
        super().__init__()
        self.cfg = cfg
        self._compiled = None
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
        if self._compiled is not None:
            return self._compiled.sdf(x)
        return self.sdf_net(x)

    def sdf_and_gradient(self, x: Tensor, create_graph: bool) -> tuple[Tensor, Tensor]:
        """SDF and its spatial gradient (not normalised). ``create_graph`` for losses on the gradient.

        With compiled queries the grid SDF writes its gradient out (:meth:`GridSDF.value_and_gradient`:
        the same values, one backward for a loss on them, so it compiles); otherwise autograd gives
        it (a loss on it: double backward)."""
        if isinstance(self.sdf_net, GridSDF) and self.sdf_net.writes_out_gradient(self._compiled is not None):
            # without create_graph nothing is differentiated through either value: no graph (and one
            # compiled variant fewer: the no-gradient one serves evaluation, probes and stage 2)
            with torch.set_grad_enabled(create_graph):
                return (self.sdf_net.value_and_gradient if self._compiled is None else self._compiled.sdf_grad)(x)
        with torch.enable_grad():
            if not x.requires_grad:
                x = x.detach().requires_grad_(True)
            d = self.sdf_net(x) if create_graph or self._compiled is None else self._compiled.sdf(x)
            (g,) = torch.autograd.grad(d, x, torch.ones_like(d), create_graph=create_graph)
        return d, g

    def compile_queries(self) -> None:
        """Run the SDF (first derivatives) and material queries through ``torch.compile``
        (:mod:`srvol.compiled`); the eikonal path's double backward stays eager."""
        from srvol.compiled import CompiledQueries
        grad = (self.sdf_net.value_and_gradient if isinstance(self.sdf_net, GridSDF) and self.sdf_net.writes_out_gradient(True)
                else None)
        self._compiled = CompiledQueries(self.sdf_net, grad, self._material_logits)

    @torch.no_grad()
    def set_coarse_to_fine(self, share: float) -> None:
        """Open the grids' levels up to ``share`` in [0, 1] of a coarse-to-fine schedule (1: all).
        The material keeps the specular head's coarse levels and the SDF its coarsest grid from the
        start; the finer levels fade in one after another. The MLP fields have no levels."""
        if self.cfg.kind != "grid":
            return
        mat, sdf = self.mat_grid.level_weights, self.sdf_net.grids.level_weights
        mat.copy_(level_window(len(mat), self.cfg.spec_levels, share))
        sdf.copy_(level_window(len(sdf), 1, share))

    # -- material
    def _material_logits(self, x: Tensor) -> tuple[Tensor, Tensor]:
        if self.cfg.kind == "paper":
            return (self.albedo_net(positional_encoding(x, self.cfg.paper_albedo_freqs)),
                    self.spec_net(positional_encoding(x, self.cfg.paper_spec_freqs)))
        feats = self.mat_grid(x)
        return self.albedo_net(feats), self.spec_net(feats[:, : self.spec_dim])

    def material(self, x: Tensor) -> SurfaceMaterial:
        """Decoded BRDF parameters: albedo = sigmoid, F0 = sigmoid, alpha in [ALPHA_MIN, 1]."""
        a, s = (self._material_logits if self._compiled is None else self._compiled.material)(x)
        albedo = torch.sigmoid(a)
        specular = torch.sigmoid(s[:, :1])
        alpha = ALPHA_MIN + (1.0 - ALPHA_MIN) * torch.sigmoid(s[:, 1:2] - 1.1)
        return SurfaceMaterial(albedo=albedo, specular=specular, alpha=alpha)

    def material_groups(self) -> tuple[list[nn.Parameter], list[nn.Parameter], list[nn.Parameter]]:
        """(albedo MLP params, specular MLP params, feature tables)."""
        tables = [self.mat_grid.table] if self.cfg.kind == "grid" else []
        return list(self.albedo_net.parameters()), list(self.spec_net.parameters()), tables


def _activation_slope(act: nn.Module, z: Tensor) -> Tensor:
    """d act(z) / dz of a head's activation (the explicit normal path of :class:`GridSDF`)."""
    if isinstance(act, SharpGELU):  # d/dz GELU(100 z) / 100 = Phi(y) + y phi(y) at y = 100 z
        y = 100.0 * z
        return 0.5 * (1.0 + torch.erf(y / math.sqrt(2.0))) + y * torch.exp(-0.5 * y * y) / math.sqrt(2.0 * math.pi)
    if isinstance(act, nn.Softplus):
        return torch.sigmoid(act.beta * z)
    raise ValueError(f"no slope for {type(act).__name__}")


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
        self.grids = DenseGrids(cfg.sdf_levels, cfg.sdf_channels, interpolation=cfg.sdf_interpolation)
        self.head = _mlp(self.grids.out_dim + 3, cfg.sdf_hidden, 1, 3, cfg.activation)
        with torch.no_grad():
            self.head[-1].weight.mul_(0.01)
            self.head[-1].bias.zero_()

    def forward(self, x: Tensor) -> Tensor:
        base = x.norm(dim=-1) - self.r0
        return base + self.head(torch.cat([x, self.grids(x)], dim=-1))[:, 0]

    explicit_gradient: bool | None = None
    """Whether :meth:`value_and_gradient` gives the normal: None (default) where the queries are
    compiled -- eagerly, autograd's double backward is ~5 % faster (``srvol bench compile``) --
    True always, False never (``bench_compile`` sets both, to time each path)."""

    def writes_out_gradient(self, compiled: bool) -> bool:
        return compiled if self.explicit_gradient is None else self.explicit_gradient

    def value_and_gradient(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """d(x) (N,) and its x-gradient (N, 3) by forward-mode differentiation written out: the
        grids' Jacobian, then the head's, layer by layer. A loss on the gradient then needs one
        backward, not autograd's double backward (and the whole query compiles)."""
        r = x.norm(dim=-1, keepdim=True)
        feats, jac = self.grids.with_jacobian(x)
        h = torch.cat([x, feats], dim=-1)
        eye = torch.eye(3, dtype=x.dtype, device=x.device).expand(x.shape[0], 3, 3)
        t = torch.cat([eye, jac], dim=-1)  # (N, 3, D): d h / d x
        for layer in self.head:
            if isinstance(layer, nn.Linear):
                h = layer(h)
                t = t @ layer.weight.t()
            else:
                t = t * _activation_slope(layer, h)[:, None, :]
                h = layer(h)
        return r[:, 0] - self.r0 + h[:, 0], x / r.clamp_min(1e-12) + t[:, :, 0]


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
