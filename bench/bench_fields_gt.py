"""What a trained run's fields learned, against a built-in scene's ground truth.

    python -m bench.bench_fields_gt RUN SCENE_NAME [--scene DIR] [--outside R] [--below Z] [--cells 0.5,0.25]

Prints, on points sampled from the GT mesh (``DIR/gt/mesh.ply``):

* the learned SDF there (median and p10/p90: a surface sitting inside reads positive);
* the learned normals against the GT surface's (analytic SDF gradient where the scene has one);
* the learned BRDF against the GT one (alpha, F0: mean, p10, p90);

and, over stage 2's own training batches (the run's PSF estimator, at each lattice cell given), the
PSNR of the training pixels for the learned fields, the learned geometry with the GT material, and
the GT geometry with the GT material (analytic scenes): the last says how well the estimator
itself reproduces the inputs; the middle one whether the learned material is what the learned
geometry can carry. ``--outside R --below Z`` split the pixels and points by where their surface
point lies (|x| > R and z < Z: e.g. glossy's outer sphere below the bowl's rim: 0.6, 0.25).
Diagnostic: prints only (the figures quoted in ``results/suite_tuning.md``).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import trimesh

from srvol.checkpoint import load_model
from srvol.config import read_run_config, sampler_of_stage
from srvol.data import load_scene
from srvol.errors import SrvolError
from srvol.losses import flash_lit
from srvol.pixels import PixelBank, sample_pixels
from srvol.psf import PsfSampler, SRMode
from srvol.render import volume_render
from srvol.synth.scenes import get_scene
from srvol.synth.surfaces import AnalyticSurface
from srvol.types import SurfaceMaterial


class _GtSdf(torch.nn.Module):
    """The GT surface's SDF in the place of a run's SDF network (float32 in, float32 out)."""

    def __init__(self, sdf):
        super().__init__()
        self.sdf = sdf

    def forward(self, x):
        return self.sdf(x.double()).float()


def _gt_material(surface):
    def material(x):
        m = surface.material(x.double())
        return SurfaceMaterial(albedo=m.albedo.float(), specular=m.specular.float(), alpha=m.alpha.float())
    return material


def _stats(a: np.ndarray) -> str:
    return f"mean {a.mean():.3f} p10 {np.percentile(a, 10):.3f} p90 {np.percentile(a, 90):.3f}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("name", help="the built-in scene the run trained on (srvol synth --list)")
    ap.add_argument("--scene", type=Path, help="its folder (default: bench/work/suite/scenes/NAME)")
    ap.add_argument("--outside", type=float, default=0.0)
    ap.add_argument("--below", type=float, default=float("inf"))
    ap.add_argument("--cells", default="0.5", help="stage 2 lattice cells to estimate with, LR px")
    ap.add_argument("--batches", type=int, default=150)
    args = ap.parse_args(argv)
    torch.set_grad_enabled(False)
    scene_dir = args.scene or Path("bench/work/suite/scenes") / args.name
    cfg = read_run_config(args.run).train
    fields, _ = load_model(args.run)
    surface = get_scene(args.name).make_surface()
    # GT normals and the GT-geometry arm from an analytic SDF only: a mesh's SDF goes through trimesh's
    # proximity query, which needs rtree (not pinned); a mesh's points take their sampled faces' normals
    analytic = isinstance(surface, AnalyticSurface)
    scene = load_scene(scene_dir)

    def region(p: np.ndarray) -> np.ndarray:
        return (np.linalg.norm(p, axis=-1) > args.outside) & (p[..., 2] < args.below)

    if not (scene_dir / "gt" / "mesh.ply").is_file():
        raise SrvolError(f"{scene_dir}: no GT mesh (gt/mesh.ply); --scene names a scene `srvol synth` wrote")
    mesh = trimesh.load(scene_dir / "gt" / "mesh.ply")
    pts, faces = trimesh.sample.sample_surface(mesh, 20000, seed=0)
    x = torch.tensor(pts, dtype=torch.float32)
    sel = region(pts)
    d = fields.sdf(x).numpy()
    print(f"learned SDF on the GT surface ({sel.sum()} points): median {np.median(d[sel]):+.5f}, "
          f"p10 {np.percentile(d[sel], 10):+.5f}, p90 {np.percentile(d[sel], 90):+.5f}")
    with torch.enable_grad():
        _, g = fields.sdf_and_gradient(x, create_graph=False)
        if analytic:
            xd = torch.tensor(pts, dtype=torch.float64, requires_grad=True)
            (gt_g,) = torch.autograd.grad(surface.sdf(xd).sum(), xd)
            n_gt = torch.nn.functional.normalize(gt_g, dim=-1).numpy()
        else:
            n_gt = mesh.face_normals[faces]
    n = torch.nn.functional.normalize(g.detach(), dim=-1).numpy()
    ang = np.degrees(np.arccos(np.clip((n * n_gt).sum(-1), -1, 1)))[sel]
    print(f"normals vs GT: median {np.median(ang):.2f} deg, p90 {np.percentile(ang, 90):.2f}")
    gt_material = _gt_material(surface)
    learned, gt = fields.material(x), gt_material(x)
    for key in ("alpha", "specular"):
        a, b = getattr(learned, key)[sel, 0].numpy(), getattr(gt, key)[sel, 0].numpy()
        print(f"{key}: learned {_stats(a)} | GT {_stats(b)}")

    bank = PixelBank(scene, torch.device("cpu"))
    psf = PsfSampler(SRMode(cfg.sr), scene.info.psf)
    intensity = torch.tensor(scene.info.light_intensity, dtype=torch.float32)
    own_sdf, own_material = fields.sdf_net, fields.material
    arms = [("learned fields", own_sdf, own_material), ("learned geometry + GT material", own_sdf, gt_material)]
    if analytic:
        arms.append(("GT geometry + GT material", _GtSdf(surface.sdf), gt_material))
    for cell in (float(c) for c in args.cells.split(",")):
        c = replace(cfg, lattice_cell=cell)
        print(f"training pixels through stage 2's estimator, lattice cell {cell} LR px:")
        for label, sdf_net, material in arms:
            fields.sdf_net, fields.material = sdf_net, material
            se = {True: 0.0, False: 0.0}
            count = {True: 0.0, False: 0.0}
            for k in range(args.batches):
                b = sample_pixels(bank, c, psf, 2, torch.Generator().manual_seed(k), 1.0)
                rays, light = flash_lit(bank, b.rays, b.ray_view, b.n_rays, intensity, None)
                vr = volume_render(fields, rays, light, sampler_of_stage(c, 2), train_geometry=False, jitter=False)
                rgb = b.estimate(vr.result.rgb)
                at = b.estimate(rays.origins + vr.result.depth[:, None] * rays.directions).numpy()
                err = (((rgb.clamp(0, 1) - b.target.clamp(0, 1)) ** 2).mean(-1) * b.mask).numpy()
                inside = region(at)
                for part in (True, False):
                    keep = inside == part
                    se[part] += float(err[keep].sum())
                    count[part] += float(b.mask.numpy()[keep].sum())
            parts = [f"{'in region' if p else 'elsewhere'} {-10 * np.log10(se[p] / count[p]):.2f} dB"
                     for p in (True, False) if count[p] > 0]
            print(f"  {label}: " + ", ".join(parts))
        fields.sdf_net, fields.material = own_sdf, own_material


if __name__ == "__main__":
    try:
        main()
    except SrvolError as e:
        sys.exit(f"bench_fields_gt: {e}")
