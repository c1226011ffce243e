"""Benchmark of `srvol synth`: wall time per built-in scene at its default size, and checks of its data.

Run as ``python -m bench.bench_synth``. For each scene it runs the real command
(``srvol synth NAME --out DIR --sheet``) in a subprocess, then measures

* seconds: wall time of the command (target <= 60 s for the default scene on 2 cores), and
  cpu_seconds, the command's CPU time (user + system; less sensitive to other jobs on the machine);
* lr_psnr_min: the worst test view's PSNR of LR input vs blur-decimate(GT HR) by the declared PSF (>= 40 dB),
  images divided by the HR peak; lr_max_abs_err the largest absolute difference, also relative to the peak;
* framing: the largest mask fraction on the image border over all views (0 = never clipped),
  and the smallest / largest mask fraction (object neither lost nor filling the frame);
* exposure: the 99th percentile of in-mask linear LR values (sensible: 0.2 .. 1.5);
* mesh: faces and signed volume of gt/mesh.ply (positive = outward winding).

Writes bench/results/synth_table.md, synth_table.json and synth_sheet_NAME.png.
"""
from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bench.paths import write_result
from srvol.data import load_scene
from srvol.metrics import psnr
from srvol.psf import blur_decimate
from srvol.synth.scenes import DEFAULT_SCENE, SCENES

RESULTS = Path(__file__).resolve().parent / "results"
TARGET_SECONDS = 60.0
TARGET_PSNR = 40.0


@dataclass(frozen=True)
class SynthRow:
    scene: str
    lr: str
    views: int
    seconds: float
    cpu_seconds: float
    lr_psnr_min: float
    lr_max_abs_err: float
    border_mask_max: float
    mask_fraction_min: float
    mask_fraction_max: float
    p99_in_mask: float
    relit_views: int
    mesh_faces: int
    mesh_volume: float


def run_synth(name: str, out: Path) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the child) of one ``srvol synth`` run."""
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "2")}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "srvol", "synth", name, "--out", str(out), "--sheet", "--force"],
                          capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"srvol synth {name} failed:\n{proc.stderr}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return seconds, cpu


def border_fraction(mask: np.ndarray) -> float:
    border = np.concatenate([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
    return float(border.mean())


def measure(name: str, out: Path, seconds: float, cpu_seconds: float) -> SynthRow:
    import trimesh

    scene = load_scene(out)
    psnrs, errs = [], []
    for stem in scene.test:
        hr = scene.gt.image("hr", stem)
        lr = blur_decimate(hr, scene.info.sr_factor, scene.info.psf_sigma_lr_px)
        peak = float(hr.max())
        psnrs.append(psnr(lr / peak, scene.views[stem].image / peak))
        errs.append(float(np.abs(lr - scene.views[stem].image).max()) / peak)
    masks = [v.mask for v in scene.views.values()]
    inside = np.concatenate([v.image[v.mask].reshape(-1) for v in scene.views.values()])
    mesh = trimesh.load(scene.gt.mesh_path, force="mesh", process=False)
    v0 = next(iter(scene.views.values()))
    return SynthRow(scene=name, lr=f"{v0.camera.width}x{v0.camera.height}", views=len(scene.views),
                    seconds=round(seconds, 1), cpu_seconds=round(cpu_seconds, 1), lr_psnr_min=round(min(psnrs), 2),
                    lr_max_abs_err=float(f"{max(errs):.3g}"),
                    border_mask_max=round(max(border_fraction(m) for m in masks), 4),
                    mask_fraction_min=round(min(float(m.mean()) for m in masks), 3),
                    mask_fraction_max=round(max(float(m.mean()) for m in masks), 3),
                    p99_in_mask=round(float(np.percentile(inside, 99)), 3),
                    relit_views=len(scene.gt.relit()), mesh_faces=len(mesh.faces),
                    mesh_volume=round(float(mesh.volume), 4))


def write_tables(rows: list[SynthRow]) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    cols = list(asdict(rows[0]))
    lines = ["# srvol synth: built-in scenes at their default size", "",
             f"Targets: default scene ({DEFAULT_SCENE}) <= {TARGET_SECONDS:.0f} s on 2 cores; "
             f"LR vs blur-decimate(HR) >= {TARGET_PSNR:.0f} dB on every test view; border_mask_max = 0 "
             "(object never clipped); mesh_volume > 0 (outward winding).", "",
             "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(v) for v in asdict(r).values()) + " |" for r in rows]
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    lines += ["", f"Machine: {os.cpu_count()} CPUs, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, "
              f"load average at the end {load} (other jobs on the machine inflate the seconds). "
              "Reproduce: `OMP_NUM_THREADS=2 python -m bench.bench_synth`."]
    write_result(RESULTS / "synth_table.md", "\n".join(lines) + "\n")
    # strict JSON has no Infinity: an exact match (infinite PSNR) is written as the string "inf"
    plain = [{k: ("inf" if v == float("inf") else v) for k, v in asdict(r).items()} for r in rows]
    write_result(RESULTS / "synth_table.json", json.dumps(plain, indent=1, allow_nan=False) + "\n")


def main(argv: list[str] | None = None) -> int:
    from srvol.cli_parser import OneLineParser

    OneLineParser(description=__doc__.splitlines()[0]).parse_args(argv)  # --help; no options
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_synth_") as tmp:
        for name in SCENES:
            out = Path(tmp) / name
            seconds, cpu = run_synth(name, out)
            row = measure(name, out, seconds, cpu)
            shutil.copyfile(out / "sheet.png", RESULTS / f"synth_sheet_{name}.png")
            rows.append(row)
            print(" ".join(f"{k}={v}" for k, v in asdict(row).items()), flush=True)
    write_tables(rows)
    default = next(r for r in rows if r.scene == DEFAULT_SCENE)
    ok = default.seconds <= TARGET_SECONDS and all(r.lr_psnr_min >= TARGET_PSNR for r in rows) \
        and all(r.border_mask_max == 0 and r.mesh_volume > 0 for r in rows)
    print(f"{'ok' if ok else 'TARGET MISSED'}: wrote {RESULTS / 'synth_table.md'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
