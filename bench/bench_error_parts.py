"""Where a run's HR error sits: the squared error of its test views split over the GT silhouette's
band, the object's highlights, the rest of the object and the background.

Run as ``python -m bench.bench_error_parts RUN [--views N]`` on a run of a synthetic scene (its
``gt/`` holds the HR views and normal maps). Each test view is rendered as ``srvol eval`` renders
it, and scored as ``psnr_hr`` scores it (both images clipped to [0, 1]). The parts:

* band: pixels within BAND_PX of the GT silhouette (inside or out);
* highlights: the object's brightest HIGHLIGHT_SHARE of pixels outside the band (GT luminance);
* rest: the other object pixels; background: the other pixels.

For each part it prints the share of the squared error, the share of the pixels, and the PSNR the
view would have were that part perfect. Prints only (a diagnosis; suite_tuning.md quotes it).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BAND_PX = 2
HIGHLIGHT_SHARE = 0.02


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
        e = split_error(vr.rgb, gt, np.linalg.norm(normal, axis=-1) > 0.5)
        print(f"{args.run.name} {stem}: HR PSNR {e.psnr:.2f} | " + " | ".join(
            f"{k} {err:.0%} of the error, {px:.1%} of the pixels, {perfect:.2f} dB if perfect"
            for k, (err, px, perfect) in e.parts.items()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
