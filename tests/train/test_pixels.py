"""Rays of the three PSF variants land where they should."""
import numpy as np
import torch

from srvol.data import load_scene
from srvol.pixels import PixelBank
from srvol.psf import GaussianPSF, PsfSampler, SRMode


def _landing(bank, scene, batch, samples):
    """Continuous LR pixel coordinates where each ray crosses the image plane of its view."""
    # every batch pixel is in one view; recover it from the ray origin
    centers = bank.centers
    origins = batch.rays.origins
    view = torch.cdist(origins, centers).argmin(dim=1)
    out = []
    for k in range(len(origins)):
        cam = scene.train_views()[int(view[k])].camera.to("cpu", torch.float32)
        p = batch.rays.origins[k] + 2.0 * batch.rays.directions[k]
        out.append(cam.project(p[None])[0])
    return torch.stack(out).reshape(-1, samples, 2)


def test_none_box_gaussian_offsets(default_scene):
    scene = load_scene(default_scene)
    bank = PixelBank(scene, torch.device("cpu"))
    sr = scene.info.sr_factor
    for mode, S in ((SRMode.NONE, 1), (SRMode.BOX, sr * sr), (SRMode.GAUSSIAN, 64)):
        g = torch.Generator().manual_seed(1)
        batch = bank.sample(6, True, PsfSampler(mode, GaussianPSF(0.375, sr)), S, g)
        samples = batch.weights.shape[2]
        assert batch.weights.shape == (6, 1, samples) and torch.allclose(batch.weights, torch.tensor(1.0 / samples))
        uv = _landing(bank, scene, batch, samples)
        centre_of_pixel = uv.mean(1) if mode != SRMode.GAUSSIAN else None
        frac = uv - uv.floor()
        if mode == SRMode.NONE:
            assert samples == 1
            assert torch.allclose(frac, torch.full_like(frac, 0.5), atol=1e-3)
        elif mode == SRMode.BOX:
            assert samples == sr * sr
            # sub-pixel centres at (k + 0.5) / sr inside the pixel, all distinct
            k = frac * sr - 0.5
            assert torch.allclose(k, k.round(), atol=1e-3)
            assert torch.allclose(centre_of_pixel - centre_of_pixel.floor(), torch.full((6, 2), 0.5), atol=1e-3)
        else:
            # spread around the pixel centre with the PSF's sigma
            c = uv.mean(1, keepdim=True).floor() + 0.5
            off = (uv - c).reshape(-1, 2)
            assert abs(float(off.std()) - 0.375) < 0.06


def test_targets_are_the_pixels_colours(default_scene):
    scene = load_scene(default_scene)
    bank = PixelBank(scene, torch.device("cpu"))
    k = int(bank.inside[17])
    v = scene.train_views()[int(bank.view[k])]
    i, j = bank.ij[k].long().tolist()
    assert np.allclose(bank.colour[k].numpy(), v.image[j, i])
    assert bool(v.mask[j, i])


def test_lattice_patches_share_rays_among_their_pixels(default_scene):
    """Each patch's rays lie on one lattice (spacing cell) over the patch and a margin, every pixel of the
    patch is estimated from all of them with weights peaked at its own centre, and the targets are the
    patch pixels' colours."""
    scene = load_scene(default_scene)
    bank = PixelBank(scene, torch.device("cpu"))
    g = torch.Generator().manual_seed(3)
    batch = bank.sample_patches(3, 4, 0.5, PsfSampler(SRMode.GAUSSIAN, GaussianPSF(0.375, 4)), g)
    G, P, R = batch.weights.shape
    assert (G, P) == (3, 16) and batch.n_rays == 3 * R and batch.n_pixels == 48
    uv = _landing(bank, scene, batch, R)  # (G, R, 2)
    steps = torch.diff(uv[..., 0].sort(dim=1).values, dim=1)
    assert torch.allclose(steps[steps > 1e-3], torch.tensor(0.5), atol=2e-3)
    for gi in range(G):
        # the heaviest ray of each pixel is within half a cell (per axis) of that pixel's centre
        best = uv[gi][batch.weights[gi].argmax(-1)]
        assert (best.frac() - 0.5).abs().max() <= 0.25 + 1e-3
    views = scene.train_views()
    k = torch.cdist(batch.rays.origins[::R], bank.centers).argmin(1)
    for gi in range(G):
        v = views[int(k[gi])]
        best = uv[gi][batch.weights[gi].argmax(-1)].floor().long()
        for p in range(P):
            i, j = best[p].tolist()
            assert np.allclose(batch.target[gi * P + p].numpy(), v.image[j, i])


def test_a_share_of_the_out_of_mask_rays_comes_from_around_the_silhouette(tmp_path):
    """A 20x16 view whose mask is the block rows 6..9, cols 8..11: its bounding box grown by 2 pixels is
    rows 4..11, cols 6..13 (64 pixels, 48 of them outside the mask). Of 200 out-of-mask pixels drawn,
    with near_share 0.5 half come from those 48, the rest from all 304 background pixels."""
    from srvol.data import SceneInfo, View, load_scene, write_scene_folder
    from srvol.pixels import SILHOUETTE_MARGIN
    from srvol.types import Camera

    assert SILHOUETTE_MARGIN == 2
    K = torch.tensor([[20.0, 0, 10], [0, 20.0, 8], [0, 0, 1]], dtype=torch.float64)
    cam = Camera.look_at([0, -3.0, 0], [0, 0, 0], [0, 0, 1], K, 20, 16)
    mask = np.zeros((16, 20), bool)
    mask[6:10, 8:12] = True
    view = View(name="000", camera=cam, image=np.full((16, 20, 3), 0.5, np.float32), mask=mask)
    write_scene_folder(tmp_path / "s", [view], SceneInfo(color_space="linear", light_intensity=(1.0, 1.0, 1.0)))
    bank = PixelBank(load_scene(tmp_path / "s"), torch.device("cpu"))
    assert len(bank.outside_near) == 64 - 16 and len(bank.outside) == 320 - 16
    psf = PsfSampler(SRMode.NONE, GaussianPSF(0.375, 4))
    batch = bank.sample(200, False, psf, 1, torch.Generator().manual_seed(0), near_share=0.5)
    assert batch.mask.sum() == 0
    ij = _landing(bank, load_scene(tmp_path / "s"), batch, 1).reshape(-1, 2).floor().long()
    near = (ij[:, 1] >= 4) & (ij[:, 1] <= 11) & (ij[:, 0] >= 6) & (ij[:, 0] <= 13)
    assert near[:100].all()  # the first half: from the grown box
    assert 5 <= int(near[100:].sum()) <= 40  # the second: anywhere (48 / 304 of the background is near)


def test_centre_sampler_gives_stage_1_the_pixel_centres_and_keeps_the_psf_for_stage_2(default_scene):
    """--psf-sampler centre: stage 1 traces one ray through each LR pixel's centre and takes N_s times
    the pixels (the same rays per step as N_s rays per pixel); stage 2 keeps the preset's PSF lattices."""
    import argparse

    from srvol.config import describe_psf_rays, psf_sampler_of_stage, rays_per_step
    from srvol.pixels import sample_pixels
    from srvol.presets import auto_config
    from srvol.train_cli import add_parser, build_config

    scene = load_scene(default_scene)
    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers())
    cfg = build_config(scene, ap.parse_args(["train", str(default_scene), "--out", "u", "--psf-sampler", "centre"]))
    assert (psf_sampler_of_stage(cfg, 1), psf_sampler_of_stage(cfg, 2)) == ("centre", "lattice")
    assert describe_psf_rays(cfg, scene.info.psf).startswith("one ray at each LR pixel's centre (2x the pixels)")
    bank = PixelBank(scene, torch.device("cpu"))
    psf = PsfSampler(SRMode.GAUSSIAN, scene.info.psf)
    one = sample_pixels(bank, cfg, psf, 1, torch.Generator().manual_seed(0))
    assert one.n_rays == len(one.target) == rays_per_step(cfg, 1) == 512  # auto's pairs: 256 pixels x 2 rays
    uv = _landing(bank, scene, one.groups(0, 8), 1)
    assert torch.allclose(uv - uv.floor(), torch.full_like(uv, 0.5), atol=1e-3)  # every ray through a centre
    two = sample_pixels(bank, cfg, psf, 2, torch.Generator().manual_seed(0))
    assert two.n_rays == sample_pixels(bank, auto_config(scene, "gaussian", 600.0), psf, 2,
                                       torch.Generator().manual_seed(0)).n_rays  # stage 2 as auto's
