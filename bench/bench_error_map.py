"""How steady stage 2's logged PSNR is, drawn uniformly or by the error map, on a finished run.

Run as ``python -m bench.bench_error_map RUN [RUN ...]``. For each run it renders every in-mask
training pixel with one ray at its centre (the finished model, stage 2's sampler), sums the squared
error of the 4x4 patch around each (what a stage-2 lattice patch centred there would hold), and
prints:

* how concentrated the error is (the share held by the worst 0.1 % and 1 % of the patches);
* the time :func:`srvol.losses.measure_error_map` takes (every in-mask pixel, as training does);
* WINDOWS windows of 25 steps of the run's patches per step, drawn uniformly and by that map at
  each share in SHARES (weighted as training weighs them): the window PSNR's median, 1st and 99th
  percentiles and its largest distance from the whole set's PSNR; and, for comparison, drawn by a map
  measured at every other pixel in each direction (training's before: a quarter of the rays) and by
  each patch's own error (the best a map could do).

``--chart OUT.png RUN ...`` draws the runs' logged stage-2 PSNR (per 25-step window, and the
probe's) against the step instead (``suite_stage2_swing.png``). Otherwise it prints only
(suite_tuning.md quotes it). The windows are drawn from the finished model's errors,
not trained: they measure the estimator, and training's own log (``bench_suite.stage2_swing_db``)
measures the runs.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

WINDOWS = 400
STEPS = 25
SHARES = (0.5, 0.8)
PATCH = 4


def window_spread(error: np.ndarray, count: np.ndarray, p: np.ndarray, per_step: int,
                  rng: np.random.Generator) -> tuple[float, float, float, float]:
    """(median, 1st percentile, 99th percentile, largest |window - truth|) of the weighted PSNR of
    WINDOWS windows of STEPS steps of ``per_step`` patches drawn with probabilities ``p``."""
    w = (1.0 / len(p)) / p
    truth = -10 * math.log10(error.sum() / count.sum())
    vals = []
    for _ in range(WINDOWS):
        idx = rng.choice(len(p), size=per_step * STEPS, p=p)
        vals.append(-10 * math.log10(max((w[idx] * error[idx]).sum() / (w[idx] * count[idx]).sum(), 1e-10)))
    vals = np.array(vals)
    return (float(np.median(vals)), float(np.percentile(vals, 1)), float(np.percentile(vals, 99)),
            float(np.abs(vals - truth).max()))


def bench_run(run: Path) -> None:
    import torch

    from srvol.checkpoint import load_model
    from srvol.config import read_run_config
    from srvol.data import load_scene
    from srvol.error_map import ErrorMap, patch_sums
    from srvol.losses import centre_squared_errors, measure_error_map
    from srvol.pixels import PixelBank, patches_per_step
    from srvol.psf import PsfSampler, SRMode

    fields, info = load_model(run)
    scene = load_scene(info.scene_dir)
    cfg = read_run_config(run).train
    bank = PixelBank(scene, torch.device("cpu"))
    psf = PsfSampler(SRMode(cfg.sr), scene.info.psf)
    intensity = torch.tensor(info.light_intensity, dtype=torch.float32)
    pixel_se = centre_squared_errors(fields, bank, bank.inside, cfg, intensity)
    error = patch_sums(bank, pixel_se, PATCH).numpy()
    count = patch_sums(bank, bank.mask.float(), PATCH).numpy()
    order = np.sort(error)[::-1]
    top = [order[: max(1, int(len(order) * q))].sum() / max(order.sum(), 1e-30) for q in (0.001, 0.01)]
    t0 = time.time()
    measured = measure_error_map(fields, bank, cfg, psf, intensity)
    seconds = time.time() - t0
    per_step = patches_per_step(cfg, psf, 2)
    truth = -10 * math.log10(error.sum() / count.sum())
    print(f"{run}: {len(bank.inside)} in-mask pixels; the worst 0.1 % of patches hold {top[0]:.0%} of the squared "
          f"error, 1 % hold {top[1]:.0%}; the map ({len(measured)} cells) measured in {seconds:.1f} s; "
          f"{per_step} patches a step; all patches {truth:.2f} dB")
    rng = np.random.default_rng(0)
    n = len(error)
    rows = [("uniform", np.full(n, 1.0 / n))]
    for share in SHARES:
        m = ErrorMap(bank, share)
        m.error = measured.error
        rows.append((f"error map, share {share:g}", m.probabilities().numpy().astype(np.float64)))
    # the map measured at every other pixel in each direction, each lending its error to its three
    # unmeasured neighbours (training's map before), and each patch's own error (the best a map could do)
    ij = bank.ij.long()
    lent = bank.view_start[bank.view] + (ij[:, 1] - ij[:, 1] % 2) * bank.sizes[bank.view, 1] + ij[:, 0] - ij[:, 0] % 2
    quarter = ErrorMap(bank, SHARES[0])
    quarter.fill(patch_sums(bank, pixel_se[lent] * bank.mask, PATCH))
    rows.append((f"quarter map, share {SHARES[0]:g}", quarter.probabilities().numpy().astype(np.float64)))
    rows.append((f"exact patches, share {SHARES[0]:g}", (1 - SHARES[0]) / n + SHARES[0] * error / error.sum()))
    print(f"  {'draw':24s} {'median':>7s} {'p1':>7s} {'p99':>7s} {'max |window - all|':>19s}  (dB, {STEPS}-step windows)")
    for name, p in rows:
        med, p1, p99, worst = window_spread(error, count, p / p.sum(), per_step, rng)
        print(f"  {name:24s} {med:7.2f} {p1:7.2f} {p99:7.2f} {worst:19.2f}")


def stage2_log(run: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(steps since stage 2 began, logged PSNR, probe PSNR) of a run's stage-2 log lines."""
    import json

    lines = [json.loads(x) for x in (run / "log.jsonl").read_text().splitlines()]
    s2 = [r for r in lines if r.get("stage") == 2]
    steps = np.array([r["step"] for r in s2], float)
    return steps - (steps[0] if len(steps) else 0), np.array([r["psnr"] for r in s2]), \
        np.array([r.get("probe_psnr", np.nan) for r in s2])


def chart(out: Path, runs: list[Path]) -> None:
    """The runs' stage-2 logged and probe PSNR against the step, one panel per run, written to ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from srvol.atomic import atomic_path

    fig, axes = plt.subplots(1, len(runs), figsize=(4.2 * len(runs), 3.2), squeeze=False, sharey=True)
    for ax, run in zip(axes[0], runs):
        steps, psnr, probe = stage2_log(run)
        ax.plot(steps, psnr, lw=1, label="logged (25-step window)")
        ax.plot(steps, probe, lw=1, label="probe (fixed pixels)")
        ax.set_title(run.name, fontsize=9)
        ax.set_xlabel("stage-2 step")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("train PSNR (dB)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    tmp = atomic_path(out)
    fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    tmp.replace(out)
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="finished run folders (srvol train --out)")
    ap.add_argument("--chart", type=Path, metavar="OUT.png",
                    help="draw the runs' stage-2 log (logged and probe PSNR) to this PNG instead")
    args = ap.parse_args(argv)
    for run in args.runs:
        if not (run / "model.pt").is_file():
            print(f"error: {run}: not a finished run (no model.pt)", file=sys.stderr)
            return 2
    if args.chart:
        chart(args.chart, args.runs)
        return 0
    for run in args.runs:
        bench_run(run)
    return 0


if __name__ == "__main__":
    sys.exit(main())
