"""Shared fixtures: an analytic sphere SDF and constant materials, so rendering and
export tests need no training."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

from srvol.types import SurfaceMaterial

torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "2")))

SPHERE_RADIUS = 0.5


def sphere_sdf(x: torch.Tensor) -> torch.Tensor:
    return x.norm(dim=-1) - SPHERE_RADIUS


def grey_material(x: torch.Tensor) -> SurfaceMaterial:
    return SurfaceMaterial.constant(x.shape[0], albedo=(0.6, 0.5, 0.4), specular=0.04, alpha=0.2,
                                    device=x.device, dtype=x.dtype)


@pytest.fixture
def sphere():
    """(sdf_fn, material_fn) of a grey sphere of radius 0.5 at the origin."""
    return sphere_sdf, grey_material


@pytest.fixture(scope="session")
def default_scene(tmp_path_factory):
    """The default built-in scene at a small size (LR 40x30, 12 + 2 views): written once per session."""
    from srvol.synth.generate import SynthOptions, synthesize

    out = tmp_path_factory.mktemp("scenes") / "bumpy_small"
    synthesize("bumpy", out, SynthOptions(lr=(40, 30), views=12, test_views=2, relit_views=1, ss=1),
               progress=False)
    return out


@pytest.fixture(scope="session")
def textured_scene(tmp_path_factory):
    """The default scene at a size stereo finds surface points in (LR 80x60, 40 + 1 views: neighbours
    within 40 deg)."""
    from srvol.synth.generate import SynthOptions, synthesize

    out = tmp_path_factory.mktemp("scenes") / "bumpy_stereo"
    synthesize("bumpy", out, SynthOptions(lr=(80, 60), views=40, test_views=1, relit_views=1, ss=1),
               progress=False)
    return out


GLTF_VALIDATOR_DIR = Path(__file__).parent / "export" / "node"
"""The Khronos glTF validator (npm gltf-validator, pinned by its package-lock.json) and validate.js."""


@pytest.fixture
def gltf_validator() -> Path:
    """validate.js of the Khronos glTF validator (``node validate.js FILE`` prints its JSON report);
    the test skips, saying why, where node or the package cannot be had."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed: the Khronos glTF validator (npm gltf-validator) cannot run")
    if not (GLTF_VALIDATOR_DIR / "node_modules" / "gltf-validator").is_dir():
        if shutil.which("npm") is None:
            pytest.skip("npm is not installed: cannot install gltf-validator")
        proc = subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=GLTF_VALIDATOR_DIR, capture_output=True,
                              text=True)
        if proc.returncode != 0:
            pytest.skip(f"npm ci of gltf-validator failed (offline?): {proc.stderr.strip()[-200:]}")
    return GLTF_VALIDATOR_DIR / "validate.js"
