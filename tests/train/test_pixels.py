"""Rays of the three PSF variants land where they should."""
import numpy as np
import torch

from srvol.data import load_scene
from srvol.pixels import PixelBank
from srvol.psf import SRMode


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
        batch = bank.sample(6, True, mode, S, 0.375, sr, g)
        uv = _landing(bank, scene, batch, batch.samples)
        centre_of_pixel = uv.mean(1) if mode != SRMode.GAUSSIAN else None
        frac = uv - uv.floor()
        if mode == SRMode.NONE:
            assert batch.samples == 1
            assert torch.allclose(frac, torch.full_like(frac, 0.5), atol=1e-3)
        elif mode == SRMode.BOX:
            assert batch.samples == sr * sr
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
