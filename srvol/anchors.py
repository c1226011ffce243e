"""Sparse surface points from the training photos themselves, found by multi-view stereo with the
views' known poses, and a loss that holds the SDF to them (the SDF term of Geo-NeuS, Fu et al. 2022,
with the line of sight to each point kept free).

Masks carve an object's outside, and the photometric loss refines a surface near where it already
is; neither opens a concavity that starts closed. Under a flash beside the lens a bowl and the dome
closing it shade alike, and stage 1 settles on the dome (the tuning scene glossy: the surface over
the bowl's centre sits at z 0.52-0.58 after 600 s, its floor at 0.30, from an initial sphere of
radius 0.5 or 0.3 alike). Stereo sees through the dome wherever the bowl's texture shows: each
view's depth is swept over the scene's bound and scored by the normalised cross-correlation of
small patches with its neighbouring views (COLMAP's and most MVS pipelines' measure; it ignores the
flash's change of brightness between views); a depth is kept where the best score is high and
unambiguous, and another view's depth map agrees with it. SIFT keypoints are too few on LR images
(10-40 per 120x90 view on the suite's scenes).

On glossy the points lie within 0.004 of the true surface (median; p90 0.015, 1.7 % beyond 0.03 --
an LR pixel covers ~0.02 there), 3353 of them, 129 on the bowl's floor; on a plain glaze (cup) stereo
sees only where the inside has a pattern. Flash highlights are left out (HIGHLIGHT_RATIO): with them,
a third of glossy's points lay 0.07 inside its ball.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from srvol.atomic import atomic_path
from srvol.data import Scene, View

NEIGHBOURS = 6
"""Views each view is compared with: the nearest by viewing direction within NEIGHBOUR_DEG."""
NEIGHBOUR_DEG = (5.0, 40.0)
"""Angle between two views' directions to the object's centre for them to be compared: closer, the
depth is poorly constrained; wider, patches no longer look alike."""
DEPTHS = 128
"""Depth hypotheses per pixel, evenly over the bound sphere's depth range (2 / 128 = 0.016 units at
bound 1, about an LR pixel's footprint on the suite's scenes)."""
PATCH = 5
"""Side of the square patches (LR pixels) whose cross-correlation scores a depth."""
MIN_SCORE = 0.6
"""Lowest kept score: the mean of the two best neighbours' correlations at the chosen depth (glossy:
at 0.8, 990 points and 1 on the bowl's floor; at 0.6, 3353 and 129, as accurate)."""
MIN_MARGIN = 0.15
"""The best score must beat the best elsewhere on the ray (beyond MARGIN_BINS) by this much."""
MARGIN_BINS = 4
MIN_TEXTURE = 0.02
"""Lowest standard deviation of a patch (grey levels 0..1) to score it at all: flat patches match
at any depth."""
HIGHLIGHT_RATIO = 3.0
"""Pixels brighter than this many times the view's median in-mask luminance are a highlight: on a
curved glossy surface the flash's reflection is a virtual image behind the surface (half the
radius behind, on a sphere), and stereo on it finds that depth. Patches touching one are not scored."""
AGREE = 0.03
"""Two views' depths of a point agree within this (scene units)."""


@dataclass(frozen=True)
class Anchors:
    """Surface points (N, 3) found by stereo; per point, its score (mean correlation of the two best
    neighbours) and the centre of the view it was found in (the line of sight between the two is
    free space)."""

    points: np.ndarray
    score: np.ndarray
    eyes: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def save(self, path: Path) -> None:
        """Write them to ``path`` (.npz), atomically."""
        tmp = atomic_path(path)
        try:
            with open(tmp, "wb") as f:
                np.savez(f, points=self.points, score=self.score, eyes=self.eyes)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)

    @staticmethod
    def load(path: Path) -> "Anchors":
        with np.load(path) as z:
            return Anchors(z["points"], z["score"], z["eyes"])


@dataclass(frozen=True)
class AnchorPoints:
    """Anchors as tensors for the loss: points (N, 3) and their views' centres (N, 3)."""

    points: Tensor
    eyes: Tensor

    @staticmethod
    def of(found: Anchors, device) -> "AnchorPoints":
        return AnchorPoints(torch.from_numpy(found.points).to(device), torch.from_numpy(found.eyes).to(device))


@dataclass(frozen=True)
class DepthMap:
    """One view's stereo depths: distance along each pixel's unit ray (H, W), NaN where none was
    kept, and the score there."""

    depth: Tensor
    score: Tensor


def luminance_and_mask(view: View) -> tuple[np.ndarray, np.ndarray]:
    """A view's linear luminance (H, W) and its mask (all True without one)."""
    lum = view.image @ np.array([0.2126, 0.7152, 0.0722])
    return lum, view.mask if view.mask is not None else np.ones(lum.shape, bool)


def highlights(view: View) -> Tensor:
    """(H, W) float: 1 on and within PATCH // 2 pixels of a highlight (HIGHLIGHT_RATIO)."""
    lum, mask = luminance_and_mask(view)
    med = float(np.median(lum[mask])) if mask.any() else 0.0
    hot = torch.from_numpy(lum > HIGHLIGHT_RATIO * max(med, 1e-8)).float()
    return F.max_pool2d(hot[None, None], PATCH, 1, PATCH // 2)[0, 0]


def grey(view: View) -> Tensor:
    """A view's image as stereo compares it: luminance scaled to its in-mask 99th percentile, gamma
    2.2 (the flash's highlights clip), (H, W)."""
    lum, mask = luminance_and_mask(view)
    top = float(np.percentile(lum[mask], 99)) if mask.any() else 1.0
    return torch.from_numpy(np.clip(lum / max(top, 1e-8), 0, 1) ** (1 / 2.2)).float()


def neighbour_views(views: list[View]) -> list[list[int]]:
    """For each view, up to NEIGHBOURS others whose direction to the scene's origin is within
    NEIGHBOUR_DEG of its own, nearest first."""
    centres = np.stack([v.camera.center.double().numpy() for v in views])
    dirs = centres / np.linalg.norm(centres, axis=-1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip(dirs @ dirs.T, -1, 1)))
    lo, hi = NEIGHBOUR_DEG
    out = []
    for a in range(len(views)):
        cand = [b for b in np.argsort(ang[a]) if b != a and lo <= ang[a, b] <= hi]
        out.append([int(b) for b in cand[:NEIGHBOURS]])
    return out


def pixel_rays(view: View) -> tuple[Tensor, Tensor]:
    """(centre (3,), unit directions (H, W, 3)) of a view's pixel centres."""
    cam = view.camera.to("cpu")  # float32
    rays = cam.rays_at(cam.pixel_centers())
    return cam.center, rays.directions.reshape(cam.height, cam.width, 3)


def project(view: View, X: Tensor) -> tuple[Tensor, Tensor]:
    """(uv (..., 2) continuous pixel coordinates, depth along the optical axis (...)) of X (..., 3)."""
    cam = view.camera
    Xc = X @ cam.W2C[:3, :3].float().T + cam.W2C[:3, 3].float()
    h = Xc @ cam.K.float().T
    return h[..., :2] / h[..., 2:].clamp_min(1e-6), Xc[..., 2]


def box_mean(x: Tensor) -> Tensor:
    """Mean over each PATCH x PATCH window of images x (N, H, W) (windows clipped at the border)."""
    return F.avg_pool2d(x[:, None], PATCH, 1, PATCH // 2, count_include_pad=False)[:, 0]


def local_stats(x: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and variance over each PATCH x PATCH window of images x (N, H, W)."""
    mu = box_mean(x)
    return mu, (box_mean(x * x) - mu * mu).clamp_min(0)


def sweep(a: int, views: list[View], greys: list[Tensor], hots: list[Tensor], nbrs: list[int],
          bound: float) -> DepthMap:
    """View ``a``'s depths by plane sweep against its neighbours (see the module)."""
    va = views[a]
    centre, dirs = pixel_rays(va)
    H, W = dirs.shape[:2]
    dist = float(centre.norm())
    t = torch.linspace(max(dist - bound, 1e-3), dist + bound, DEPTHS)
    ga = greys[a][None]
    mu_a, var_a = local_stats(ga)
    X = centre + t[:, None, None, None] * dirs  # (D, H, W, 3): each pixel's depth hypotheses
    ncc = []
    for b in nbrs:
        vb = views[b]
        Hb, Wb = greys[b].shape
        uv, z = project(vb, X)
        grid = torch.stack([uv[..., 0] / Wb * 2 - 1, uv[..., 1] / Hb * 2 - 1], -1)
        pair = torch.stack([greys[b], hots[b]])[None].expand(DEPTHS, 2, Hb, Wb)
        both = F.grid_sample(pair, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
        warped, hot = both[:, 0], both[:, 1]  # (D, H, W)
        mu_w, var_w = local_stats(warped)
        cov = box_mean(ga * warped) - mu_a * mu_w
        c = cov / (var_a * var_w + 1e-8).sqrt()
        inside = (z > 0) & (grid.abs() <= 1).all(-1)
        hot = F.max_pool2d(hot[:, None], PATCH, 1, PATCH // 2)[:, 0] > 0
        ncc.append(torch.where(inside & ~hot & (var_w > MIN_TEXTURE ** 2), c, torch.full_like(c, -1.0)))
    if not ncc:
        return DepthMap(torch.full((H, W), float("nan")), torch.zeros(H, W))
    stack = torch.stack(ncc)  # (K, D, H, W)
    k = min(2, len(ncc))
    score = stack.topk(k, dim=0).values.mean(0)  # (D, H, W)
    best, idx = score.max(0)
    bins = torch.arange(DEPTHS)[:, None, None]
    far = (bins - idx[None]).abs() > MARGIN_BINS
    second = torch.where(far, score, torch.full_like(score, -1.0)).max(0).values
    mask = torch.from_numpy(va.mask) if va.mask is not None else torch.ones(H, W, dtype=torch.bool)
    keep = mask & (hots[a] == 0) & (best >= MIN_SCORE) & (best - second >= MIN_MARGIN) & (var_a[0] > MIN_TEXTURE ** 2)
    keep &= (idx > 0) & (idx < DEPTHS - 1)
    # sub-bin depth: the parabola through the best score and its two neighbours
    i0 = idx.clamp(1, DEPTHS - 2)
    s_m, s_0, s_p = (score.gather(0, (i0 + o)[None])[0] for o in (-1, 0, 1))
    off = (0.5 * (s_m - s_p) / (s_m - 2 * s_0 + s_p).clamp(max=-1e-6)).clamp(-0.5, 0.5)
    depth = t[i0] + off * (t[1] - t[0])
    return DepthMap(torch.where(keep, depth, torch.full_like(depth, float("nan"))), best)


def find_anchors(scene: Scene, bound: float = 1.0) -> Anchors:
    """Stereo surface points over the scene's training views that another view's depth map agrees
    with (see the module)."""
    views = scene.train_views()
    greys = [grey(v) for v in views]
    hots = [highlights(v) for v in views]
    nbrs = neighbour_views(views)
    maps = [sweep(a, views, greys, hots, nbrs[a], bound) for a in range(len(views))]
    pts, scores, eyes = [], [], []
    for a, m in enumerate(maps):
        centre, dirs = pixel_rays(views[a])
        ok = torch.isfinite(m.depth)
        if not ok.any():
            continue
        X = centre + m.depth[ok][:, None] * dirs[ok]
        agree = torch.zeros(len(X), dtype=torch.bool)
        for b in nbrs[a]:
            cb = views[b].camera.center.float()
            uv, z = project(views[b], X)
            Hb, Wb = maps[b].depth.shape
            i, j = uv[:, 0].floor().long(), uv[:, 1].floor().long()
            inside = (z > 0) & (i >= 0) & (i < Wb) & (j >= 0) & (j < Hb)
            db = torch.full((len(X),), float("nan"))
            db[inside] = maps[b].depth[j[inside], i[inside]]
            agree |= ((X - cb).norm(dim=-1) - db).abs() <= AGREE
        if agree.any():
            pts.append(X[agree])
            scores.append(m.score[ok][agree])
            eyes.append(centre.expand(int(agree.sum()), 3))
    if not pts:
        return Anchors(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros((0, 3), np.float32))
    return Anchors(torch.cat(pts).numpy(), torch.cat(scores).numpy(), torch.cat(eyes).numpy())


FREE_SPACE_MARGIN = 0.05
"""The line of sight to an anchor is free space up to this far (scene units) before it: a few LR
pixels' footprint at the suite's distances, beyond a triangulated point's error."""
FREE_SPACE_SAMPLES = 4
"""Points drawn on each anchor's line of sight per step."""
ANCHOR_TOLERANCE = 0.015
"""A point pulls the surface only from further than this (scene units): the stereo points lie within
it of the surface for 90 % of them (tuning scene glossy: median 0.004, p90 0.015), and pulled all the
way they would print their own noise into the surface the photometric loss refines."""


class AnchorTerms(NamedTuple):
    """The two terms over a draw of anchors (:func:`anchor_terms`)."""

    pull: Tensor
    """mean max(|d(p)| - ANCHOR_TOLERANCE, 0) over the points: the surface held to them."""
    free_space: Tensor
    """mean max(-d(x), 0) over points x on their lines of sight: nothing stands in front of them."""


def anchor_terms(sdf_at, points: Tensor, eyes: Tensor, n: int, gen: torch.Generator,
                 bound: float = 1.0) -> AnchorTerms:
    """Both anchor terms over ``n`` anchors drawn at random: the pull, and the free space along each
    one's line of sight from its view to it (inside the ``bound`` sphere, up to FREE_SPACE_MARGIN
    before it). ``sdf_at``: x -> d(x).

    The pull alone is met by an SDF that stays negative and only touches zero at the points under a
    lid; the free space opens the lid. The free space alone never pulls the surface to a point: a
    point's own error (beyond the margin) is what it can print into the surface."""
    idx = torch.randint(len(points), (min(n, len(points)),), generator=gen).to(points.device)
    p, e = points[idx], eyes[idx]
    seg = p - e
    length = seg.norm(dim=-1, keepdim=True)
    d = seg / length
    # where the line of sight enters the bound sphere: |e + t d| = bound
    b = (e * d).sum(-1, keepdim=True)
    enter = (-b - (b * b - (e * e).sum(-1, keepdim=True) + bound ** 2).clamp_min(0).sqrt()).clamp_min(0)
    stop = (length - FREE_SPACE_MARGIN).clamp_min(enter)
    u = torch.rand(len(p), FREE_SPACE_SAMPLES, generator=gen).to(p.device)
    x = e[:, None] + (enter + u * (stop - enter))[..., None] * d[:, None]
    free = torch.relu(-sdf_at(x.reshape(-1, 3))).mean()
    return AnchorTerms(pull=torch.relu(sdf_at(p).abs() - ANCHOR_TOLERANCE).mean(), free_space=free)
