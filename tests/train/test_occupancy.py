"""The evaluation occupancy grid: rays that cannot meet the surface are not traced, and the image
is the one the full renderer gives."""
import math

import torch

from srvol.occupancy import OccupancyGrid
from srvol.render import SamplerConfig, render_chunked
from srvol.types import Camera, PointLight
from sphere_fields import sphere_fields


def _camera(width: int = 48, height: int = 36) -> Camera:
    """Looking at the origin from 3 units along -z with a 40-degree field of view."""
    f = 0.5 * width / math.tan(math.radians(20))
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
    return Camera.look_at((0, 0, -3), (0, 0, 0), (0, 1, 0), K, width, height).to("cpu", torch.float32)


def test_a_ball_occupies_its_shell_and_interior_only():
    """A ball of radius 0.3: the corner cells of the cube are > 1 unit from it and stay empty; the
    centre cell (inside) and a cell on the surface are occupied."""
    f = sphere_fields(0.3, 0.002)
    grid = OccupancyGrid.of_sdf(f.sdf, 0.002, resolution=32)
    occ = grid.occupied
    assert not occ[0, 0, 0] and not occ[-1, -1, -1]
    assert occ[16, 16, 16]
    assert occ[16, 16, int((0.3 + 1.0) / grid.cell)]
    # occupied cells reach no further than the slack allows: |x| < 0.3 + reach + one dilated cell
    reach = 2.0 * 0.5 * math.sqrt(3) * grid.cell + 20 * 0.002 + 2 * grid.cell
    centres = (torch.nonzero(occ).float() + 0.5) * grid.cell - 1.0
    assert float(centres.norm(dim=-1).max()) < 0.3 + reach


def test_the_grid_skips_background_rays_and_changes_no_pixel():
    f = sphere_fields(0.3, 0.003)
    cam = _camera()
    rays = cam.rays_at(cam.pixel_centers())
    light = PointLight.at_camera(cam, (5.0, 5.0, 5.0))
    sampler = SamplerConfig(n_coarse=32, n_importance=8, n_uniform=2, n_refine=4)
    grid = OccupancyGrid.of_sdf(f.sdf, float(f.beta.detach()), sampler.bound)
    live = grid.rays_that_may_hit(rays, sampler.bound)
    full = render_chunked(f, rays, lambda r: light, sampler, chunk=512)
    fast = render_chunked(f, rays, lambda r: light, sampler, chunk=512, occupancy=grid)
    assert 0.1 < float(live.float().mean()) < 0.7  # the ball covers ~1/4 of the view: most rays are skipped
    assert float(full.opacity[~live].max()) < 1e-6  # nothing the full renderer saw is lost
    assert torch.equal(fast.opacity, full.opacity)
    assert torch.allclose(fast.rgb, full.rgb, atol=1e-6)
    assert torch.allclose(fast.normal, full.normal, atol=1e-6)


def test_an_empty_grid_traces_no_ray():
    f = sphere_fields(0.3, 0.002)
    with torch.no_grad():  # push the whole SDF far above zero: no surface anywhere
        f.sdf_net.head[-1].bias.add_(5.0)
    grid = OccupancyGrid.of_sdf(f.sdf, 0.002, resolution=16)
    assert grid.fraction == 0.0
    cam = _camera(8, 6)
    assert not grid.rays_that_may_hit(cam.rays_at(cam.pixel_centers()), 1.0).any()
