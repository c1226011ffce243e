"""Fixtures of the relighting tests; the scenes themselves live in relight_scenes.py."""
from __future__ import annotations

import pytest

from relight_scenes import SphereOnPlane


@pytest.fixture
def sphere_on_plane() -> SphereOnPlane:
    return SphereOnPlane()
