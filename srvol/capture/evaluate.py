"""``srvol eval RUN --gt GT``: a run trained on an imported capture, scored in the GT's frame.

1. Align: a similarity fitted on the photos' camera centres (imported scene frame -> GT frame);
   each photo's rotation error after it.
2. The GT's held-out views (gt/hr_cameras.json, GT frame) are mapped into the scene frame and
   rendered there with the run's co-located flash. Intensity and exposure of a capture are unknown,
   so **one per-channel gain** (least squares over all held-out views) scales the renders before
   psnr_hr / ssim_hr / psnr_hr_masked; the same gain scales the relit renders.
3. Normals are rotated into the GT frame (normal_mae_deg); albedo_psnr as for a synthetic scene
   (its own per-channel scale).
4. Moved lights (gt/relit.json) are mapped into the scene frame; their intensity relative to the GT's
   flash (gt/capture.json) is carried over to the run's flash intensity.
5. Chamfer: the run's zero level set, mapped into the GT frame, against gt/mesh.ply (units of the GT
   mesh's bounding-box diagonal).

The renderers are passed in (``render``: HR camera, light -> image, normals, albedo; ``relit``:
with shadows; ``fields``: anything with ``sdf``, for the Chamfer distance), so that the alignment and
scoring are tested with exact analytic renders.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from srvol import metrics
from srvol.capture.compare import CameraAlignment, align_cameras, gt_photo_cameras
from srvol.capture.frame import Similarity
from srvol.data import GroundTruth, Scene, read_cameras_json
from srvol.errors import SrvolError
from srvol.types import Camera, PointLight

ViewRenderFn = Callable[[Camera, PointLight], "object"]
"""(camera, light) -> an object with rgb (H, W, 3), opacity (H, W), normal (H, W, 3), albedo (H, W, 3)."""
RelitFn = Callable[[Camera, PointLight], np.ndarray]


@dataclass(frozen=True)
class HeldOutRender:
    name: str
    gt: np.ndarray
    pred: np.ndarray
    fg: np.ndarray
    normal_gt: np.ndarray
    normal_pred: np.ndarray
    opacity: np.ndarray
    albedo_gt: np.ndarray | None
    albedo_pred: np.ndarray


def channel_gain(preds: list[np.ndarray], gts: list[np.ndarray]) -> np.ndarray:
    """(3,) per-channel least-squares gain g minimising sum |g pred - gt|^2 over all the images."""
    p = np.concatenate([x.reshape(-1, 3) for x in preds]).astype(np.float64)
    g = np.concatenate([x.reshape(-1, 3) for x in gts]).astype(np.float64)
    return (p * g).sum(0) / np.maximum((p * p).sum(0), 1e-12)


def light_in_scene(light: PointLight, gt_to_scene: Similarity, flash_gt: float, flash_run) -> PointLight:
    """A GT-frame light in the scene frame, its intensity re-expressed relative to the run's flash."""
    pos = gt_to_scene.apply(light.position.double().numpy()[None])[0]
    ratio = light.intensity.double().numpy() / flash_gt
    return PointLight.make(pos.tolist(), (ratio * np.asarray(flash_run, np.float64)).tolist())


def evaluate_capture(scene: Scene, gt_dir: Path, render: ViewRenderFn, flash_intensity,
                     relit: RelitFn | None = None, fields=None, out_dir: Path | None = None) -> dict:
    """Metrics of a run on an imported capture against the capture's GT folder (module docstring)."""
    gt_dir = Path(gt_dir)
    gt = GroundTruth(gt_dir)
    align = align_cameras({n: v.camera for n, v in scene.views.items()}, gt_photo_cameras(gt_dir))
    to_scene = align.scene_to_gt.inverse()
    hr_path = gt_dir / "hr_cameras.json"
    if not hr_path.is_file():
        raise SrvolError(f"{hr_path}: no held-out cameras in the GT folder")
    renders = []
    for name, cam_gt in read_cameras_json(hr_path).items():
        hr = gt.image("hr", name)
        normal_gt = gt.image("normal", name)
        if hr is None or normal_gt is None:
            raise SrvolError(f"{gt_dir / 'hr' / (name + '.exr')}: missing HR image or normals of held-out view {name}")
        cam = to_scene.camera(cam_gt)
        vr = render(cam, PointLight.at_camera(cam, flash_intensity))
        n = np.asarray(vr.normal, np.float64) @ align.scene_to_gt.rotation.T
        renders.append(HeldOutRender(name=name, gt=hr, pred=np.asarray(vr.rgb, np.float32),
                                     fg=np.linalg.norm(normal_gt, axis=-1) > 0.5, normal_gt=normal_gt,
                                     normal_pred=n.astype(np.float32), opacity=np.asarray(vr.opacity),
                                     albedo_gt=gt.image("albedo", name), albedo_pred=np.asarray(vr.albedo)))
    gain = channel_gain([r.pred for r in renders], [r.gt for r in renders])
    out = _alignment_metrics(align)
    out["gain"] = [float(v) for v in gain]
    per_view = []
    for r in renders:
        pred = r.pred * gain
        m = {"view": r.name, "psnr_hr": metrics.psnr(pred, r.gt), "ssim_hr": metrics.ssim(pred, r.gt),
             "psnr_hr_masked": metrics.psnr(pred, r.gt, mask=r.fg)}
        sel = r.fg & (r.opacity > 0.5)
        if sel.any():
            m["normal_mae_deg"] = metrics.normal_mae_deg(r.normal_pred, r.normal_gt, sel)
            if r.albedo_gt is not None:
                m["albedo_psnr"] = metrics.albedo_psnr(r.albedo_pred, r.albedo_gt, sel)
        per_view.append(m)
    for k in ("psnr_hr", "ssim_hr", "psnr_hr_masked", "normal_mae_deg", "albedo_psnr"):
        vals = [m[k] for m in per_view if k in m]
        if vals:
            out[k] = float(np.mean(vals))
    if relit is not None:
        out.update(_relit_metrics(gt, gt_dir, to_scene, flash_intensity, relit, gain))
    if fields is not None and gt.mesh_path.is_file():
        from srvol.evaluate import chamfer_to_gt

        out["chamfer"] = chamfer_to_gt(fields, gt.mesh_path, to_gt=align.scene_to_gt.apply)
    out["views"] = per_view
    if out_dir is not None:
        _write_sheet(out_dir, renders, gain, out)
    return out


def _alignment_metrics(align: CameraAlignment) -> dict:
    return {"registered": align.registered_share, "rotation_median_deg": align.median_rotation_deg,
            "rotation_max_deg": float(max(align.rotation_deg.values())),
            "center_error_median": float(np.median(list(align.center_error.values())))}


def _relit_metrics(gt: GroundTruth, gt_dir: Path, to_scene: Similarity, flash_run, relit: RelitFn,
                   gain: np.ndarray) -> dict:
    specs = gt.relit()
    if not specs:
        return {}
    cap = gt_dir / "capture.json"
    if not cap.is_file():
        raise SrvolError(f"{cap}: the GT folder does not record its flash intensity")
    flash_gt = float(json.loads(cap.read_text())["light_intensity"])
    cams = read_cameras_json(gt_dir / "hr_cameras.json")
    ps, ss = [], []
    for spec in specs:
        img = gt.image("relit", spec.name)
        if img is None or spec.camera not in cams:
            continue
        pred = relit(to_scene.camera(cams[spec.camera]), light_in_scene(spec.light, to_scene, flash_gt, flash_run))
        pred = np.asarray(pred) * gain
        ps.append(metrics.psnr(pred, img))
        ss.append(metrics.ssim(pred, img))
    return {"relit_psnr": float(np.mean(ps)), "relit_ssim": float(np.mean(ss))} if ps else {}


def _write_sheet(out_dir: Path, renders: list[HeldOutRender], gain: np.ndarray, summary: dict) -> None:
    from srvol.sheets import error_to_rgb, normal_to_rgb, write_sheet

    rows = [[("GT HR", r.gt), ("ours x gain", r.pred * gain), ("|error| x4", error_to_rgb(np.abs(r.pred * gain - r.gt), 0.25)),
             ("normals (ours)", normal_to_rgb(r.normal_pred)), ("normals (GT)", normal_to_rgb(r.normal_gt))]
            for r in renders[:4]]
    out_dir.mkdir(parents=True, exist_ok=True)
    write_sheet(out_dir / "eval_sheet.png", rows, encoded_labels=("|error| x4", "normals (ours)", "normals (GT)"),
                title=f"capture eval: PSNR {summary.get('psnr_hr', float('nan')):.2f} dB (gain-aligned), "
                      f"rotation {summary['rotation_median_deg']:.2f} deg")
