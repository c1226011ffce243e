"""Options of ``srvol synth``: image size, PSF, views and framing of a synthetic capture.

Every built-in scene carries its own ``SynthOptions`` (``srvol.synth.scenes.SCENES``); the
command-line flags override single fields of it.
"""
from __future__ import annotations

from dataclasses import dataclass

from srvol.errors import SrvolError
from srvol.psf import DEFAULT_SIGMA_LR_PX


@dataclass(frozen=True)
class SynthOptions:
    """lr: (W, H) of the LR inputs; sr: HR/LR ratio; views: training views;
    test_views: held-out views; psf_sigma: Gaussian PSF sigma in LR pixels;
    ss: sub-pixel rays per HR pixel side; relit_views: test views rendered under moved lights;
    lights_per_view: moved lights per relit view (the k-th relit view starts at light pattern k,
    so three relit views with one light each cover three different light placements).

    Framing (1, (0, 0), 1 = the default scene's): zoom: apparent object size, the cameras stand
    at the default distance / zoom (the area the object covers grows about as zoom^2);
    aim: where the object's centre sits in the frame, in fractions of the half-width and
    half-height (x right, y down; the cameras turn, they do not move); exposure: the flash's
    intensity relative to the default at the same distance (the intensity scales with 1/zoom^2,
    so exposure 1 lights the object as brightly at any zoom).
    mesh_resolution: grid samples across [-1, 1] for the GT mesh of an analytic surface."""

    lr: tuple[int, int] = (120, 90)
    sr: int = 4
    views: int = 40
    test_views: int = 8
    psf_sigma: float = DEFAULT_SIGMA_LR_PX
    seed: int = 0
    ss: int = 2
    relit_views: int = 3
    lights_per_view: int = 1
    zoom: float = 1.0
    aim: tuple[float, float] = (0.0, 0.0)
    exposure: float = 1.0
    mesh_resolution: int = 256

    def validate(self) -> None:
        W, H = self.lr
        if W < 8 or H < 8:
            raise SrvolError(f"--lr {W}x{H}: too small (at least 8x8)")
        if self.sr < 1 or self.sr > 16:
            raise SrvolError(f"--sr {self.sr}: must be 1..16")
        if self.views < 1 or self.test_views < 1:
            raise SrvolError("--views and --test-views must be >= 1")
        if not (0 <= self.psf_sigma <= 5):
            raise SrvolError(f"--psf-sigma {self.psf_sigma}: must be in [0, 5] LR pixels")
        if not (0.3 <= self.zoom <= 2.0):
            raise SrvolError(f"zoom {self.zoom}: must be in [0.3, 2] (the camera stays outside the unit sphere)")
        if not all(abs(a) <= 0.9 for a in self.aim):
            raise SrvolError(f"aim {self.aim}: each coordinate must be in [-0.9, 0.9] half-frames")
        if not (self.exposure > 0):
            raise SrvolError(f"exposure {self.exposure}: must be > 0")
        if self.mesh_resolution < 16:
            raise SrvolError(f"mesh resolution {self.mesh_resolution}: must be >= 16")
