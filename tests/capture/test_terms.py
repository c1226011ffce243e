"""The real-capture terms reproduce how ``srvol synth --capture`` forms its photos (before noise)."""
from __future__ import annotations

import math

import numpy as np
import torch

from srvol.capture.terms import CaptureTerms, CaptureTermsConfig, radial2
from srvol.synth.capture import CaptureOptions, flash_position, vignetting_map
from srvol.types import Camera


def test_vignetting_and_gain_match_the_synthetic_photos():
    opts = CaptureOptions()
    W, H = 32, 24
    vmap = torch.from_numpy(vignetting_map(W, H, opts.vignetting))
    terms = CaptureTerms(3, torch.tensor([0, 0, 0]))
    with torch.no_grad():
        terms.vignetting[0] = torch.tensor(opts.vignetting)
        terms.log_gain[:] = torch.log(torch.tensor([5.0, 2.0, 0.5]))
        terms.set_ambient([0.01, 0.01, 0.01])
    j, i = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    uv = torch.stack([i.reshape(-1) + 0.5, j.reshape(-1) + 0.5], -1).float()
    radiance, albedo = torch.rand(W * H, 3), torch.rand(W * H, 3)
    view = torch.full((W * H,), 1)
    got = terms.apply(radiance, albedo, view, radial2(uv, W, H))
    want = 2.0 * vmap.reshape(-1, 1) * (radiance + 0.01 * albedo)
    assert torch.allclose(got, want, atol=1e-5)
    ref = terms.apply(radiance, albedo, torch.zeros(W * H, dtype=torch.long), radial2(uv, W, H))
    assert torch.allclose(ref, vmap.reshape(-1, 1) * (radiance + 0.01 * albedo), atol=1e-5)  # reference: gain 1


def test_flash_position_matches_the_synthetic_flash():
    K = torch.tensor([[50.0, 0, 16], [0, 50.0, 12], [0, 0, 1]], dtype=torch.float64)
    cams = [Camera.look_at([2.5 * math.cos(a), 2.5 * math.sin(a), 0.7], [0, 0, 0], [0, 0, 1], K, 32, 24)
            for a in (0.3, 1.9)]
    offset = (0.12, -0.03, 0.0)
    terms = CaptureTerms(2, torch.tensor([0, 0]), CaptureTermsConfig(flash_offset=offset))
    got = terms.flash_position(torch.stack([c.center.float() for c in cams]),
                               torch.stack([c.W2C[:3, :3].float() for c in cams]))
    want = np.stack([flash_position(c, offset) for c in cams])
    assert np.allclose(got.detach().numpy(), want, atol=1e-5)
    assert not terms.flash_offset.requires_grad  # given, not learned


def test_the_reference_photo_gain_gets_no_gradient():
    terms = CaptureTerms(3, torch.tensor([0, 0, 1]), CaptureTermsConfig(reference_view=1))
    out = terms.apply(torch.ones(3, 3), torch.ones(3, 3), torch.tensor([0, 1, 2]), torch.zeros(3))
    out.sum().backward()
    assert terms.log_gain.grad[1] == 0 and terms.log_gain.grad[0] != 0 and terms.log_gain.grad[2] != 0
    assert terms.vignetting.shape == (2, 2)
