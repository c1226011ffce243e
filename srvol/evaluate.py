"""``srvol eval``: render the held-out test views at HR and score them against the GT.

Metric keys: DESIGN.md section 5 (``srvol.metrics.METRIC_KEYS``). PSNR over the
full image as the paper (``psnr_hr``), and over the object mask (``psnr_hr_masked``).
Only held-out test views are scored; training views never enter a generalisation metric.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from srvol import metrics
from srvol.data import Scene
from srvol.errors import SrvolError
from srvol.occupancy import OccupancyGrid
from srvol.psf import blur_decimate
from srvol.render import SamplerConfig, render_chunked
from srvol.sheets import error_to_rgb, normal_to_rgb, write_sheet
from srvol.types import Camera, PointLight, RenderResult


@dataclass(frozen=True)
class ViewRender:
    rgb: np.ndarray  # (H, W, 3) linear
    opacity: np.ndarray  # (H, W)
    normal: np.ndarray  # (H, W, 3) unit where opacity > 0.5, else 0
    albedo: np.ndarray  # (H, W, 3) at the expected surface point


def occupancy_of(fields, sampler: SamplerConfig) -> OccupancyGrid:
    """The occupancy grid that spares evaluation the rays that cannot meet the surface."""
    return OccupancyGrid.of_sdf(fields.sdf, float(fields.beta.detach()), sampler.bound)


def render_view(fields, camera: Camera, light: PointLight, sampler: SamplerConfig, chunk: int = 8192,
                occupancy: OccupancyGrid | None = None) -> ViewRender:
    """Volume-render a whole image of ``camera`` under ``light`` (e.g. the co-located flash).
    ``occupancy``: the fields' grid, shared by the views of one evaluation (built here without it)."""
    cam = camera.to("cpu", torch.float32)
    rays = cam.rays_at(cam.pixel_centers())
    occupancy = occupancy if occupancy is not None else occupancy_of(fields, sampler)
    res: RenderResult = render_chunked(fields, rays, lambda r: light, sampler, chunk=chunk, occupancy=occupancy)
    H, W = cam.height, cam.width
    op = res.opacity.reshape(H, W).numpy()
    n = res.normal.reshape(H, W, 3).numpy()
    nn_ = np.linalg.norm(n, axis=-1, keepdims=True)
    normal = np.where((op[..., None] > 0.5) & (nn_ > 1e-6), n / np.maximum(nn_, 1e-6), 0.0)
    depth = (res.depth / res.opacity.clamp_min(1e-6))
    pts = rays.origins + depth[:, None] * rays.directions
    albedo = torch.zeros(H * W, 3)
    sel = torch.nonzero(res.opacity > 0.5).squeeze(-1)
    with torch.no_grad():
        for s in range(0, sel.numel(), chunk):
            idx = sel[s:s + chunk]
            albedo[idx] = fields.material(pts[idx]).albedo
    return ViewRender(rgb=res.rgb.reshape(H, W, 3).numpy(), opacity=op, normal=normal.astype(np.float32),
                      albedo=albedo.reshape(H, W, 3).numpy())


RelitFn = Callable[[Camera, PointLight], np.ndarray]
"""(HR camera, moved light) -> (H, W, 3) linear render with shadows (srvol.relight provides it)."""


def evaluate_run(fields, scene: Scene, sampler: SamplerConfig, intensity, out_dir: Path | None,
                 views: list[str] | None = None, progress: bool = True, relit_fn: RelitFn | None = None) -> dict:
    """Metrics over the scene's held-out test views (requires gt/hr); writes sheets to ``out_dir``.

    ``relit_fn`` renders the model under the GT's moved lights (relit_psnr, relit_ssim);
    without it those keys are absent.
    """
    test = views or scene.test
    if not test:
        raise SrvolError(f"{scene.root}: the scene has no held-out test views (scene.json split.test)")
    from tqdm import tqdm

    per_view = []
    sheet_rows = []
    occupancy = occupancy_of(fields, sampler)
    for stem in tqdm(test, desc="eval", unit="view", disable=not progress):
        gt_hr = scene.gt.image("hr", stem)
        if gt_hr is None:
            raise SrvolError(f"{scene.gt.root / 'hr' / (stem + '.exr')}: no HR ground truth for test view {stem}")
        cam = scene.hr_camera(stem)
        light = PointLight.at_camera(cam, intensity).to("cpu")
        vr = render_view(fields, cam, light, sampler, occupancy=occupancy)
        m: dict = {"view": stem}
        mask = scene.gt.image("normal", stem)
        fg = gt_foreground(scene, stem)
        m["psnr_hr"] = metrics.psnr(vr.rgb, gt_hr)
        m["ssim_hr"] = metrics.ssim(vr.rgb, gt_hr)
        if fg is not None:
            m["psnr_hr_masked"] = metrics.psnr(vr.rgb, gt_hr, mask=fg)
            m["dark_fraction"] = metrics.dark_fraction(vr.rgb, gt_hr, fg)
            m["normal_mae_deg"] = metrics.normal_mae_deg(vr.normal, mask, fg & (vr.opacity > 0.5))
        lr_pred = blur_decimate(vr.rgb, scene.info.sr_factor, scene.info.psf_sigma_lr_px)
        m["psnr_lr"] = metrics.psnr(lr_pred, scene.views[stem].image)
        gt_alb = scene.gt.image("albedo", stem)
        if gt_alb is not None and fg is not None:
            m["albedo_psnr"] = metrics.albedo_psnr(vr.albedo, gt_alb, fg & (vr.opacity > 0.5))
        per_view.append(m)
        if out_dir is not None and len(sheet_rows) < 4:
            err = np.abs(vr.rgb - gt_hr)
            sheet_rows.append([("GT HR", gt_hr), ("ours", vr.rgb), ("|error| x4", error_to_rgb(err, 0.25)),
                               ("normals (ours)", normal_to_rgb(vr.normal)),
                               ("normals (GT)", normal_to_rgb(mask) if mask is not None else np.zeros_like(gt_hr)),
                               ("LR input", scene.views[stem].image)])
    keys = sorted({k for m in per_view for k in m if k != "view"})
    summary = {k: float(np.mean([m[k] for m in per_view if k in m])) for k in keys}
    relit = scene.gt.relit() if relit_fn is not None else []
    if relit:
        rp, rs = [], []
        for spec in relit:
            gt = scene.gt.image("relit", spec.name)
            if gt is None:
                continue
            rp_s = relit_fn(scene.hr_camera(spec.camera), spec.light)
            rp.append(metrics.psnr(rp_s, gt))
            rs.append(metrics.ssim(rp_s, gt))
            if out_dir is not None:
                sheet_rows.append([(f"GT relit {spec.name}", gt), ("ours relit", rp_s),
                                   ("|error| x4", error_to_rgb(np.abs(rp_s - gt), 0.25))])
        if rp:
            summary["relit_psnr"] = float(np.mean(rp))
            summary["relit_ssim"] = float(np.mean(rs))
    if scene.gt.mesh_path.is_file():
        summary["chamfer"] = chamfer_to_gt(fields, scene.gt.mesh_path)
    if out_dir is not None and sheet_rows:
        out_dir.mkdir(parents=True, exist_ok=True)
        write_sheet(out_dir / "eval_sheet.png", sheet_rows,
                    encoded_labels=("|error| x4", "normals (ours)", "normals (GT)"),
                    title=f"eval: PSNR {summary.get('psnr_hr', float('nan')):.2f} dB, "
                          f"normal MAE {summary.get('normal_mae_deg', float('nan')):.2f} deg")
    summary["views"] = per_view
    return summary


def gt_foreground(scene: Scene, stem: str) -> np.ndarray | None:
    """(H, W) bool HR object mask of a test view: where the GT normal map is set (None without it)."""
    normal = scene.gt.image("normal", stem)
    return (np.linalg.norm(normal, axis=-1) > 0.5) if normal is not None else None


def upsample_bicubic(image: np.ndarray, factor: int) -> np.ndarray:
    """(H, W, 3) -> (factor H, factor W, 3): cubic spline zoom with pixel-area alignment, clipped at 0."""
    from scipy.ndimage import zoom

    return np.stack([zoom(image[..., c], factor, order=3, grid_mode=True, mode="nearest")
                     for c in range(image.shape[-1])], -1).clip(0, None)


def bicubic_reference(scene: Scene, views: list[str] | None = None) -> dict:
    """psnr_hr, ssim_hr, psnr_hr_masked of each test view's own LR image upsampled bicubically,
    against its HR GT, averaged over ``views`` (default: all test views). A 2D reference that
    sees the test view's LR pixels, which no 3D method is given."""
    per_view = []
    for stem in views or scene.test:
        gt = scene.gt.image("hr", stem)
        up = upsample_bicubic(scene.views[stem].image, scene.info.sr_factor)
        m = {"psnr_hr": metrics.psnr(up, gt), "ssim_hr": metrics.ssim(up, gt)}
        fg = gt_foreground(scene, stem)
        if fg is not None:
            m["psnr_hr_masked"] = metrics.psnr(up, gt, mask=fg)
        per_view.append(m)
    return {k: float(np.mean([m[k] for m in per_view])) for k in per_view[0]}


def chamfer_to_gt(fields, mesh_path: Path, resolution: int = 128, n_points: int = 30000,
                  to_gt: Callable[[np.ndarray], np.ndarray] | None = None) -> float:
    """Chamfer distance between the zero level set (marching cubes) and the GT mesh, in bbox diagonals.

    ``to_gt`` maps the level set's vertices (N, 3) into the GT mesh's frame (an imported capture's
    scene frame differs from its GT's; ``srvol.capture.evaluate``)."""
    import trimesh
    from skimage.measure import marching_cubes

    lin = torch.linspace(-1, 1, resolution)
    pts = torch.stack(torch.meshgrid(lin, lin, lin, indexing="ij"), -1).reshape(-1, 3)
    with torch.no_grad():
        d = torch.cat([fields.sdf(pts[s:s + 65536]) for s in range(0, len(pts), 65536)])
    vol = d.reshape(resolution, resolution, resolution).numpy()
    if vol.min() > 0 or vol.max() < 0:
        raise SrvolError("the SDF has no surface inside the unit sphere")
    step = 2.0 / (resolution - 1)
    v, f, _, _ = marching_cubes(vol, 0.0, spacing=(step,) * 3)
    v = v - 1.0
    ours = trimesh.Trimesh(to_gt(v) if to_gt is not None else v, f, process=False)
    gt = trimesh.load(mesh_path, force="mesh")
    rng = np.random.default_rng(0)
    a = trimesh.sample.sample_surface(ours, n_points, seed=rng)[0]
    b = trimesh.sample.sample_surface(gt, n_points, seed=rng)[0]
    return metrics.chamfer(a, b)


def write_metrics(path: Path, summary: dict) -> None:
    from srvol.atomic import atomic_write_text

    atomic_write_text(path, json.dumps(summary, indent=1))
