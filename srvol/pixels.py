"""Training pixels of a scene and the rays that estimate them under the PSF."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from srvol.data import Scene
from srvol.psf import SRMode, pixel_offsets
from srvol.types import Rays


@dataclass(frozen=True)
class PixelBatch:
    """P LR pixels, each estimated by S sub-pixel rays (``rays`` has P * S entries, pixel-major).

    target (P, 3) linear colour; mask (P,) foreground in {0, 1}; samples S.
    """

    rays: Rays
    target: Tensor
    mask: Tensor
    samples: int


class PixelBank:
    """All LR training pixels, split by the mask, with per-view camera tensors for batched rays."""

    def __init__(self, scene: Scene, device: torch.device):
        views = scene.train_views()
        self.device = device
        self.has_masks = scene.has_masks
        Ks = torch.stack([v.camera.K.float() for v in views])
        W2C = torch.stack([v.camera.W2C.float() for v in views])
        self.K_inv = torch.linalg.inv(Ks).to(device)
        self.R_T = W2C[:, :3, :3].transpose(1, 2).contiguous().to(device)
        self.centers = torch.stack([v.camera.center.float() for v in views]).to(device)
        colours, masks, vid, ij = [], [], [], []
        for k, v in enumerate(views):
            H, W = v.image.shape[:2]
            jj, ii = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
            colours.append(v.image.reshape(-1, 3))
            masks.append((v.mask if v.mask is not None else np.ones((H, W), bool)).reshape(-1))
            vid.append(np.full(H * W, k))
            ij.append(np.stack([ii.reshape(-1), jj.reshape(-1)], -1))
        self.colour = torch.from_numpy(np.concatenate(colours)).float().to(device)
        self.mask = torch.from_numpy(np.concatenate(masks)).to(device)
        self.view = torch.from_numpy(np.concatenate(vid)).long().to(device)
        self.ij = torch.from_numpy(np.concatenate(ij)).float().to(device)
        self.inside = torch.nonzero(self.mask).squeeze(-1)
        self.outside = torch.nonzero(~self.mask).squeeze(-1)

    def rays(self, view: Tensor, uv: Tensor) -> Rays:
        """Rays of views ``view`` (P,) through continuous pixel coordinates ``uv`` (P, S, 2)."""
        P, S, _ = uv.shape
        hom = torch.cat([uv, torch.ones(P, S, 1, device=uv.device)], -1)
        d_cam = torch.einsum("pij,psj->psi", self.K_inv[view], hom)
        d = torch.einsum("pij,psj->psi", self.R_T[view], d_cam)
        d = d / d.norm(dim=-1, keepdim=True)
        o = self.centers[view][:, None, :].expand(P, S, 3)
        return Rays(origins=o.reshape(-1, 3), directions=d.reshape(-1, 3))

    def sample(self, n: int, inside: bool, mode: SRMode, psf_samples: int, sigma: float, sr: int,
               generator: torch.Generator) -> PixelBatch:
        pool = self.inside if inside else self.outside
        pick = pool[torch.randint(len(pool), (n,), generator=generator).to(pool.device)]
        offsets = pixel_offsets(mode, n, psf_samples, sigma, sr, generator=generator).to(self.device)
        uv = self.ij[pick][:, None, :] + 0.5 + offsets
        return PixelBatch(rays=self.rays(self.view[pick], uv), target=self.colour[pick],
                          mask=self.mask[pick].float(), samples=offsets.shape[1])
