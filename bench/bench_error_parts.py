"""Where a run's HR error sits: the squared error of its test views split over the GT silhouette's
band, the object's highlights, the rest of the object and the background.

Run as ``python -m bench.bench_error_parts RUN [--views N]`` on a run of a synthetic scene (its
``gt/`` holds the HR views and normal maps). Each test view is rendered as ``srvol eval`` renders
it, and scored as ``psnr_hr`` scores it (both images clipped to [0, 1]). The parts:

* band: pixels within BAND_PX of the GT silhouette (inside or out);
* highlights: the object's brightest HIGHLIGHT_SHARE of pixels outside the band (GT luminance);
* rest: the other object pixels; background: the other pixels.

For each part it prints the share of the squared error, the share of the pixels, and the PSNR the
view would have were that part perfect; then the normal MAE (as ``srvol eval`` scores it) by distance
from the GT silhouette in HR pixels (:data:`NORMAL_RINGS`). Prints only (a diagnosis;
suite_tuning.md quotes it).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BAND_PX = 2
HIGHLIGHT_SHARE = 0.02
NORMAL_RINGS = ((0, 2), (2, 4), (4, 8), (8, None))
"""Distance rings (HR pixels, inside the GT silhouette: (lo, hi]) of :func:`normal_error_by_ring`."""


@dataclass(frozen=True)
class ErrorParts:
    """Per part: (share of the squared error, share of the pixels, PSNR were the part perfect)."""

    psnr: float
    parts: dict[str, tuple[float, float, float]]


def split_error(pred: np.ndarray, gt: np.ndarray, object_mask: np.ndarray) -> ErrorParts:
    """The squared error of ``pred`` against ``gt`` ((H, W, 3), clipped to [0, 1]) over the parts."""
    from scipy import ndimage

    se = ((np.clip(pred, 0, 1) - np.clip(gt, 0, 1)) ** 2).sum(-1)
    inner = ndimage.binary_erosion(object_mask, iterations=BAND_PX)
    outer = ndimage.binary_dilation(object_mask, iterations=BAND_PX)
    band = outer & ~inner
    lum = gt.mean(-1)
    body = object_mask & ~band
    hi = body & (lum > np.percentile(lum[body], 100 * (1 - HIGHLIGHT_SHARE))) if body.any() else body
    parts = {"band": band, "highlights": hi, "rest": body & ~hi, "background": ~outer}
    total = float(se.sum())
    n = se.size * 3

    def psnr_of(sse: float) -> float:
        return float("inf") if sse <= 0 else 10 * np.log10(n / sse)

    return ErrorParts(psnr=psnr_of(total), parts={
        k: (float(se[m].sum()) / max(total, 1e-30), float(m.mean()), psnr_of(total - float(se[m].sum())))
        for k, m in parts.items()})


def normal_error_by_ring(pred_normal: np.ndarray, gt_normal: np.ndarray, scored: np.ndarray,
                         object_mask: np.ndarray) -> list[tuple[tuple[int, int | None], float, float]]:
    """Per ring of :data:`NORMAL_RINGS`: (ring, normal MAE in degrees over its ``scored`` pixels,
    share of the scored pixels), distance measured inward from the edge of ``object_mask``."""
    from scipy import ndimage

    from srvol.metrics import normal_mae_deg

    depth = ndimage.distance_transform_edt(object_mask)
    rows = []
    for lo, hi in NORMAL_RINGS:
        ring = scored & (depth > lo) & (depth <= (np.inf if hi is None else hi))
        mae = normal_mae_deg(pred_normal, gt_normal, ring) if ring.any() else float("nan")
        rows.append(((lo, hi), mae, float(ring.sum()) / max(int(scored.sum()), 1)))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.bench_error_parts", description=__doc__.split("\n")[0])
    p.add_argument("run", type=Path, help="a run folder of a synthetic scene")
    p.add_argument("--views", type=int, default=0, help="the first N test views (default: all)")
    args = p.parse_args(argv)
    from srvol.checkpoint import load_model
    from srvol.config import read_run_config
    from srvol.data import load_scene
    from srvol.evaluate import occupancy_of, render_view
    from srvol.types import PointLight

    fields, info = load_model(args.run)
    scene = load_scene(info.scene_dir)
    sampler = read_run_config(args.run).train.sampler
    occupancy = occupancy_of(fields, sampler)
    for stem in scene.test[: args.views or None]:
        cam = scene.hr_camera(stem)
        gt = scene.gt.image("hr", stem)
        normal = scene.gt.image("normal", stem)
        if gt is None or normal is None:
            raise SystemExit(f"{args.run}: its scene has no GT HR view or normal map for {stem}")
        vr = render_view(fields, cam, PointLight.at_camera(cam, info.light_intensity), sampler, occupancy=occupancy)
        obj = np.linalg.norm(normal, axis=-1) > 0.5
        e = split_error(vr.rgb, gt, obj)
        print(f"{args.run.name} {stem}: HR PSNR {e.psnr:.2f} | " + " | ".join(
            f"{k} {err:.0%} of the error, {px:.1%} of the pixels, {perfect:.2f} dB if perfect"
            for k, (err, px, perfect) in e.parts.items()), flush=True)
        rings = normal_error_by_ring(vr.normal, normal, obj & (vr.opacity > 0.5), obj)
        print(f"{args.run.name} {stem}: normal MAE by HR px from the silhouette | " + " | ".join(
            f"({lo}, {'inf' if hi is None else hi}] {mae:.1f} deg on {share:.0%}" for (lo, hi), mae, share in rings),
            flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
