"""Speed-accuracy sweep, stability matrix and capacity study (the charts users choose a method by).

    python -m bench.bench_study [--budget 120] [--only sweep,stability,capacity] [--collect | --from-results]

Every run is ``srvol train`` with one ``--time-budget`` followed by ``srvol eval`` on the same
held-out views; each table row records both commands. Three studies:

1. sweep: presets x ``--sr gaussian|box|none`` x N_s in {1, 5, 10, 15, 25} (Monte Carlo PSF rays
   per LR pixel, the paper's table of samples per pixel against quality and time), auto's shared
   lattice, the fast preset, and bicubic-upsampled LR inputs as the floor.
2. stability: the default scene with image noise sigma in {0.01, 0.03, 0.05}, 8/16/32 training
   views, the PSF sigma misestimated (x0.5, x2), camera pose noise (0.25, 0.5, 1 deg), clipped
   highlights, a very dark albedo and a near-mirror coat. A run that collapses, produces NaN or
   renders dark is reported as such (``status``), never as a number.
3. capacity: auto against x0.5 and x2 of its scene-derived capacity, and the paper's networks.

Writes bench/results/study_{sweep,stability,capacity}.{md,json} and .png. Runs and derived
scenes live in bench/work/study/ (not committed).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bench.bench_train import RESULTS, WORK, _run, ensure_scene, scored_on
from bench.paths import write_result
from srvol.cli_parser import OneLineParser

STUDY = WORK / "study"
EVAL_VIEWS = ("040", "041")
METRICS = ("psnr_hr", "ssim_hr", "psnr_hr_masked", "normal_mae_deg", "albedo_psnr", "chamfer", "dark_fraction")


# ----------------------------------------------------------------------------- derived scenes

@dataclass(frozen=True)
class SceneVariant:
    """A scene for the study: a built-in scene, optionally with its training inputs perturbed.

    noise: Gaussian image noise sigma (linear units); views: keep this many training views
    (evenly spread); psf_scale: multiply the PSF sigma written in scene.json (the images keep
    the true blur: a misestimated PSF); pose_deg: rotate every training camera by this angle
    about a random axis through its centre (wrong poses, right images); clip: clip images at
    this quantile of the foreground values (saturated highlights). Test views and GT are
    never touched: the scores are against the truth.
    """

    key: str
    builtin: str = "bumpy"
    noise: float = 0.0
    views: int = 0
    psf_scale: float = 1.0
    pose_deg: float = 0.0
    clip: float = 0.0

    @property
    def perturbed(self) -> bool:
        return bool(self.noise or self.views or self.psf_scale != 1.0 or self.pose_deg or self.clip)


def _rotate_camera(cam, angle_deg: float, rng: np.random.Generator):
    """The same camera turned by ``angle_deg`` about a random axis through its centre."""
    import torch

    from srvol.types import Camera

    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = math.radians(angle_deg)
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    Rd = np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx
    W2C = cam.W2C.double().numpy().copy()
    c = cam.center.double().numpy()
    R = Rd @ W2C[:3, :3]
    W2C[:3, :3] = R
    W2C[:3, 3] = -R @ c
    return Camera(K=cam.K, W2C=torch.from_numpy(W2C).to(cam.W2C.dtype), width=cam.width, height=cam.height)


def derive_scene(variant: SceneVariant) -> Path:
    """The variant's scene folder (built once): the built-in scene with its training inputs perturbed."""
    base = ensure_scene(variant.builtin)
    if not variant.perturbed:
        return base
    out = STUDY / "scenes" / variant.key
    if (out / "scene.json").is_file():
        return out
    from srvol.atomic import AtomicFolder
    from srvol.data import load_scene, write_scene_folder

    scene = load_scene(base)
    rng = np.random.default_rng(0)
    train = list(scene.train)
    if variant.views:
        keep = np.linspace(0, len(train) - 1, variant.views).round().astype(int)
        train = [train[k] for k in keep]
    fg = np.concatenate([v.image[v.mask] for v in scene.train_views()]) if scene.has_masks else None
    clip_at = float(np.quantile(fg, variant.clip)) if variant.clip and fg is not None else None
    views = []
    for v in scene.views.values():
        if v.name in scene.train:
            img = v.image
            if clip_at is not None:
                img = np.minimum(img, clip_at)
            if variant.noise:
                img = np.clip(img + rng.normal(0.0, variant.noise, img.shape), 0.0, None).astype(np.float32)
            cam = _rotate_camera(v.camera, variant.pose_deg, rng) if variant.pose_deg else v.camera
            v = replace(v, image=img, camera=cam)
        views.append(v)
    info = replace(scene.info, train=tuple(train),
                   psf_sigma_lr_px=scene.info.psf_sigma_lr_px * variant.psf_scale)
    with AtomicFolder(out, force=True) as tmp:
        write_scene_folder(tmp, views, info)
        (tmp / "gt").symlink_to((base / "gt").resolve())
    return out


# ----------------------------------------------------------------------------- runs

@dataclass(frozen=True)
class Variant:
    study: str
    label: str
    scene: SceneVariant
    train_args: tuple[str, ...] = ()
    group: str = ""


@dataclass
class Row:
    study: str
    label: str
    group: str
    scene: str
    status: str = "ok"
    metrics: dict = field(default_factory=dict)
    iterations: int = 0
    train_seconds: float = 0.0
    parameters: int = 0
    command: str = ""


REFERENCE = Variant("sweep", "auto default", SceneVariant("bumpy"), ("--sr", "gaussian"), "default")
"""auto as a user runs it: the sweep's centre, the stability matrix's reference, the capacity study's x1."""


def _sweep() -> list[Variant]:
    s = SceneVariant("bumpy")
    out = [Variant("sweep", f"auto gaussian MC N_s={n}", s, ("--sr", "gaussian", "--psf-sampler", "mc", "--psf-samples", str(n)),
                   "mc")
           for n in (1, 5, 10, 15, 25)]
    out += [REFERENCE,
            Variant("sweep", "auto gaussian shared lattice", s, ("--sr", "gaussian", "--psf-sampler", "lattice"),
                    "lattice"),
            Variant("sweep", "auto box (Vol-SR)", s, ("--sr", "box"), "box"),
            Variant("sweep", "auto none (noSR)", s, ("--sr", "none"), "none"),
            Variant("sweep", "fast gaussian MC N_s=4", s, ("--preset", "fast", "--sr", "gaussian"), "fast")]
    return out


def _stability() -> list[Variant]:
    v = []
    for n in (0.01, 0.03, 0.05):
        v.append(Variant("stability", f"noise {n}", SceneVariant(f"noise{n}", noise=n), group="image noise"))
    for k in (8, 16, 32):
        v.append(Variant("stability", f"{k} views", SceneVariant(f"views{k}", views=k), group="views"))
    for f in (0.5, 2.0):
        v.append(Variant("stability", f"PSF sigma x{f:g}", SceneVariant(f"psf{f:g}", psf_scale=f), group="PSF misestimate"))
    for d in (0.25, 0.5, 1.0):
        v.append(Variant("stability", f"pose noise {d:g} deg", SceneVariant(f"pose{d:g}", pose_deg=d), group="pose noise"))
    v.append(Variant("stability", "highlights clipped (q=0.95)", SceneVariant("clip95", clip=0.95), group="clipping"))
    v.append(Variant("stability", "very dark albedo", SceneVariant("dark", builtin="dark"), group="material"))
    v.append(Variant("stability", "near-mirror coat", SceneVariant("shiny", builtin="shiny"), group="material"))
    return v


def _capacity() -> list[Variant]:
    s = SceneVariant("bumpy")
    return [Variant("capacity", f"auto x{c:g}", s, ("--capacity", str(c)), f"{c:g}") for c in (0.5, 2.0)] + [
        Variant("capacity", "paper networks", s, ("--preset", "paper"), "paper")]


def run_variant(var: Variant, budget: float, collect: bool) -> Row:
    scene = derive_scene(var.scene)
    slug = "".join(ch if ch.isalnum() else "_" for ch in var.label).strip("_")
    run = STUDY / "runs" / f"{var.study}_{slug}_{int(budget)}s"
    train = ["srvol", "train", str(scene), "--out", str(run), "--time-budget", f"{budget:g}", "--quiet", "--force",
             *var.train_args]
    ev = ["srvol", "eval", str(run), "--views", ",".join(EVAL_VIEWS), "--no-relit"]
    paper = "paper" in var.train_args
    row = Row(var.study, var.label, var.group, var.scene.key,
              command=" ".join(train) + ("" if paper else " && " + " ".join(ev)))
    try:
        if not (collect and (run / "train_summary.json").is_file()):
            error = _train(train)
            if error:
                row.status = "failed: " + error
                return row
        summary = json.loads((run / "train_summary.json").read_text())
        row.iterations, row.train_seconds = summary["iterations"], summary["train_seconds"]
        row.parameters = summary.get("parameters", 0)
        if paper:  # the paper MLPs take hours to render HR views on a CPU: scored by their log
            row.status = "log only"
            row.metrics = {"train_psnr_lr": summary["final_train_psnr"]}
            return row
        if not (collect and scored_on(run / "metrics.json") == list(EVAL_VIEWS)):  # scored on other views: again
            _run([sys.executable, "-m", "srvol", *ev[1:]])
        m = json.loads((run / "metrics.json").read_text())
        row.metrics = {k: m[k] for k in METRICS if k in m}
        row.status = output_status(m)
    except RuntimeError as e:
        row.status = "failed: " + str(e)
    return row


def load_rows(name: str) -> list[Row]:
    """The rows of a committed study table (bench/results/study_NAME.json)."""
    path = RESULTS / f"study_{name}.json"
    if not path.is_file():
        raise SystemExit(f"bench_study: {path} not found; run the study first")
    return [Row(**d) for d in json.loads(path.read_text())]


def recorded_budget(rows: list[Row]) -> float:
    """The --time-budget the rows were trained with (read back from their commands)."""
    toks = rows[0].command.split()
    return float(toks[toks.index("--time-budget") + 1])


def _train(cmd: list[str]) -> str | None:
    """Run a training command; None on success, else its last stderr line (srvol's one-line error)."""
    import os
    import subprocess

    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "2"))
    p = subprocess.run([sys.executable, "-m", "srvol", *cmd[1:]], env=env, capture_output=True, text=True)
    sys.stdout.write(p.stdout)
    if p.returncode == 0:
        return None
    lines = [x for x in p.stderr.strip().splitlines() if x.strip()]
    return lines[-1] if lines else f"exit {p.returncode}"


def output_status(m: dict) -> str:
    """'ok', or what is wrong with the output: NaN/inf metrics, a dark or empty render."""
    vals = [m.get(k) for k in ("psnr_hr", "ssim_hr", "normal_mae_deg")]
    if any(v is None or not math.isfinite(v) for v in vals):
        return "non-finite metrics"
    if m.get("dark_fraction", 0.0) > 0.5:
        return f"dark render ({m['dark_fraction']:.0%} of foreground pixels)"
    return "ok"


def bicubic_floor(scene_dir: Path) -> dict:
    """HR PSNR / SSIM of bicubic-upsampled LR test images against the HR GT (no 3D at all)."""
    from srvol.data import load_scene
    from srvol.evaluate import bicubic_reference

    return bicubic_reference(load_scene(scene_dir), list(EVAL_VIEWS))


# ----------------------------------------------------------------------------- output

def _fmt(v, spec: str) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def write_table(name: str, rows: list[Row], budget: float, extra: list[str]) -> None:
    RESULTS.mkdir(exist_ok=True)
    write_result(RESULTS / f"study_{name}.json", json.dumps([r.__dict__ for r in rows], indent=1, default=str))
    lines = [f"# {name}: {budget:.0f} s training budget per run, 2-core CPU, views {', '.join(EVAL_VIEWS)}", "",
             "Reproduce: `python -m bench.bench_study --only " + name + f" --budget {budget:g}` "
             "(each row's own commands are listed below).", "",
             "| run | status | HR PSNR | SSIM | masked PSNR | normal MAE (deg) | albedo PSNR | dark pixels | Chamfer "
             "| iterations | s/iteration | parameters |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        m = r.metrics
        status = r.status
        if "train_psnr_lr" in m:
            status += f" (train PSNR on training pixels {m['train_psnr_lr']:.2f} dB)"
        spi = r.train_seconds / r.iterations if r.iterations else float("nan")
        lines.append(f"| {r.label} | {status} | {_fmt(m.get('psnr_hr'), '.2f')} | {_fmt(m.get('ssim_hr'), '.3f')} | "
                     f"{_fmt(m.get('psnr_hr_masked'), '.2f')} | {_fmt(m.get('normal_mae_deg'), '.2f')} | "
                     f"{_fmt(m.get('albedo_psnr'), '.2f')} | {_fmt(m.get('dark_fraction'), '.1%')} | "
                     f"{_fmt(m.get('chamfer'), '.4f')} | {r.iterations} | {_fmt(spi, '.3f')} | "
                     f"{r.parameters / 1e6:.2f} M |")
    lines += ["", *extra, "", "Commands:", ""] + [f"- {r.label}: `{r.command}`" for r in rows]
    write_result(RESULTS / f"study_{name}.md", "\n".join(lines) + "\n")
    print("\n".join(lines), flush=True)


def chart_sweep(rows: list[Row], floor: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    mc = [r for r in rows if r.group == "mc" and r.status == "ok"]
    ns = [int(r.label.split("=")[1]) for r in mc]
    for ax, key, name in ((axes[0], "psnr_hr", "HR PSNR (dB)"), (axes[1], "normal_mae_deg", "normal MAE (deg)")):
        ax.plot(ns, [r.metrics[key] for r in mc], "o-", label="gaussian MC")
        for r, style in ((next((x for x in rows if x.group == g and x.status == "ok"), None), s)
                         for g, s in (("default", "C5-"), ("lattice", "C1--"), ("none", "C2:"), ("box", "C3-."),
                                      ("fast", "C4--"))):
            if r is not None:
                ax.axhline(r.metrics[key], color=style[:2], linestyle=style[2:], label=r.label)
        if key == "psnr_hr":
            ax.axhline(floor["psnr_hr"], color="k", linestyle=":", label="bicubic of the test view's LR image (2D)")
        ax.set_xlabel("PSF rays per LR pixel N_s")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    axes[2].plot(ns, [r.train_seconds / max(r.iterations, 1) for r in mc], "o-")
    axes[2].set_xlabel("PSF rays per LR pixel N_s")
    axes[2].set_ylabel("seconds per iteration")
    axes[2].grid(alpha=0.3)
    fig.suptitle("samples per pixel against quality and time (equal wall-clock budget)")
    fig.tight_layout()
    fig.savefig(RESULTS / "study_sweep.png", dpi=110)


def chart_bars(name: str, rows: list[Row], ref: Row | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = ([ref] if ref else []) + [r for r in rows if r.status != "log only"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.35 * len(shown) + 1.5))
    labels = [r.label + ("" if r.status == "ok" else f" [{r.status}]") for r in shown]
    for ax, key, xl in ((axes[0], "psnr_hr", "HR PSNR (dB)"), (axes[1], "normal_mae_deg", "normal MAE (deg)")):
        vals = [r.metrics.get(key, float("nan")) for r in shown]
        ax.barh(range(len(shown)), [0 if not math.isfinite(v) else v for v in vals],
                color=["C7" if r is ref else ("C0" if r.status == "ok" else "C3") for r in shown])
        finite = [v for v in vals if math.isfinite(v)]
        for i, v in enumerate(vals):
            if math.isfinite(v):
                ax.text(v, i, f" {v:.2f}", va="center", fontsize=7)
        if key == "psnr_hr" and finite:  # dB has no natural zero: start a little below the lowest bar
            ax.set_xlim(left=max(0.0, math.floor(min(finite)) - 2), right=max(finite) + 1.5)
        ax.set_yticks(range(len(shown)), labels, fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel(xl)
        ax.grid(alpha=0.3, axis="x")
    fig.suptitle(f"{name} (grey: the default scene, auto)")
    fig.tight_layout()
    fig.savefig(RESULTS / f"study_{name}.png", dpi=110)


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--budget", type=float, default=120.0, help="training seconds per run (default 120)")
    ap.add_argument("--only", default="sweep,stability,capacity", help="comma list of studies")
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--collect", action="store_true", help="reuse finished runs; rebuild tables and charts")
    mode.add_argument("--from-results", action="store_true",
                      help="no training: rebuild the tables and charts from bench/results/study_*.json")
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    studies = [s for s in args.only.split(",") if s]
    unknown = set(studies) - {"sweep", "stability", "capacity"}
    if unknown:
        ap.error(f"--only: unknown study {', '.join(sorted(unknown))} (sweep, stability, capacity)")
    t0 = time.time()
    budget = args.budget
    provenance = (["Rebuilt from the recorded rows (`--from-results`, no training): they were measured with the "
                   "code of the commit that last changed the rows' JSON; `python -m bench.bench_study` re-measures."]
                  if args.from_results else [])
    if args.from_results:  # each table keeps its own budget and reference row
        recorded = {name: load_rows(name) for name in studies}
        budget_of = lambda name: recorded_budget(recorded[name])  # noqa: E731

        def ref_for(name: str) -> Row:
            rows = recorded[name] if any(r.group == REFERENCE.group for r in recorded[name]) else load_rows("sweep")
            return next(r for r in rows if r.group == REFERENCE.group)

        measured = lambda name, variants: recorded[name]  # noqa: E731
    else:
        ref = run_variant(REFERENCE, budget, args.collect)
        budget_of = lambda name: budget  # noqa: E731
        ref_for = lambda name: ref  # noqa: E731
        measured = lambda name, variants: [  # noqa: E731
            ref if v is REFERENCE else run_variant(v, budget, args.collect) for v in variants]
    if "sweep" in studies:
        rows = measured("sweep", _sweep())
        floor = bicubic_floor(ensure_scene("bumpy"))
        write_table("sweep", rows, budget_of("sweep"), [
            f"2D baseline (dotted line in the chart): bicubic upsampling of each held-out view's own LR image, "
            f"HR PSNR {floor['psnr_hr']:.2f} dB, SSIM {floor['ssim_hr']:.3f}. It sees the test view's LR pixels, "
            "which no 3D method is given, so it is a reference, not a floor.",
            "Paper (one scene, days on a GPU): N_s 5 -> 25 moved PSNR 27.68 -> 28.39 dB while time went 26 h -> 75 h.",
            *provenance])
        chart_sweep(rows, floor)
    if "stability" in studies:
        rows = measured("stability", _stability())
        ref = ref_for("stability")
        write_table("stability", rows, budget_of("stability"), [
            f"Reference (default scene, auto): HR PSNR {_fmt(ref.metrics.get('psnr_hr'), '.2f')} dB, "
            f"normal MAE {_fmt(ref.metrics.get('normal_mae_deg'), '.2f')} deg.",
            "status: ok, or how the run failed -- a collapsed SDF, non-finite metrics or a dark render are "
            "detected and named, never scored. dark pixels: share of foreground pixels rendered near black.",
            *provenance])
        chart_bars("stability", rows, ref)
    if "capacity" in studies:
        rows = measured("capacity", [REFERENCE, *_capacity()])
        write_table("capacity", rows, budget_of("capacity"), [
            "auto x1 is auto as a user runs it (the sweep's centre); x0.5 / x2 scale its grids, hash table and "
            "head widths (`srvol train --capacity`). The paper networks are scored by their training log "
            "(rendering HR views with 5x512 MLPs takes hours on a CPU).", *provenance])
        chart_bars("capacity", rows[1:], ref_for("capacity"))
    print(f"study done in {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
