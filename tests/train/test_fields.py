"""The grid fields: a rounded ReLU with second derivatives, SDF grids that draw a plane flat, and old runs load as trained."""
import torch

from srvol.encodings import DenseGrids
from srvol.fields import FieldConfig, SceneFields, SharpGELU


def test_sharp_gelu_is_a_relu_rounded_over_a_hundredth():
    x = torch.linspace(-1.0, 1.0, 2001)
    y = SharpGELU()(x)
    assert float((y - torch.relu(x)).abs().max()) < 0.002
    assert float((y - torch.relu(x)).abs()[x.abs() > 0.05].max()) < 1e-6
    # like Softplus(beta=100), it has a second derivative at the kink (the eikonal's double backward)
    x0 = torch.zeros(1, requires_grad=True)
    (g,) = torch.autograd.grad(SharpGELU()(x0).sum(), x0, create_graph=True)
    (h,) = torch.autograd.grad(g.sum(), x0)
    assert abs(float(g.detach()) - 0.5) < 1e-6 and float(h) > 30.0


def test_a_config_saved_before_the_activation_choice_loads_with_softplus():
    saved = FieldConfig(activation="softplus").to_json()
    del saved["activation"]
    old = FieldConfig.from_json(saved)
    assert old.activation == "softplus"
    assert isinstance(SceneFields(old, learn_intensity=False).sdf_net.head[1], torch.nn.Softplus)
    assert isinstance(SceneFields(FieldConfig(), learn_intensity=False).sdf_net.head[1], SharpGELU)


def _tilted_plane_grid(interpolation: str, res: int = 16) -> DenseGrids:
    """One level, one channel, each node holding 0.3 i + 0.5 j - 0.2 k (a plane through the grid)."""
    grid = DenseGrids((res,), 1, interpolation=interpolation)
    i, j, k = torch.meshgrid(*[torch.arange(res, dtype=torch.float32)] * 3, indexing="ij")
    with torch.no_grad():
        grid.table[:] = (0.3 * i + 0.5 * j - 0.2 * k).reshape(-1, 1)
    return grid


def test_bspline_sdf_grids_draw_a_tilted_plane_with_one_normal_where_smoothstep_terraces_it():
    x = (torch.rand(2000, 3, generator=torch.Generator().manual_seed(0)) * 1.6 - 0.8).requires_grad_(True)
    u = (x.detach() + 1) * 0.5 * 15  # grid coordinates of res 16
    slope = torch.tensor([0.3, 0.5, -0.2]) * 7.5  # d(node value)/dx: 7.5 grid steps per scene unit
    bspline = _tilted_plane_grid("bspline")
    value = bspline(x)[:, 0]
    assert float((value.detach() - u @ torch.tensor([0.3, 0.5, -0.2])).abs().max()) < 1e-4  # exact on a plane
    (g,) = torch.autograd.grad(value.sum(), x)
    assert float((g - slope).abs().max()) < 1e-4  # one gradient everywhere: the normal does not wobble
    (g_smooth,) = torch.autograd.grad(_tilted_plane_grid("smoothstep")(x)[:, 0].sum(), x)
    # smoothstep's slope is 0 at every node and 1.5x the plane's between them: the normal turns cell by cell
    assert float(g_smooth[:, 1].min()) < 0.2 * float(slope[1]) and float(g_smooth[:, 1].max()) > 1.4 * float(slope[1])


def test_a_config_saved_before_the_interpolation_choice_loads_with_smoothstep():
    saved = FieldConfig(sdf_interpolation="smoothstep").to_json()
    del saved["sdf_interpolation"]
    assert FieldConfig.from_json(saved).sdf_interpolation == "smoothstep"
    assert SceneFields(FieldConfig(sdf_interpolation="bspline"), learn_intensity=False).sdf_net.grids.interpolation == "bspline"


def test_sdf_interpolation_flag_reaches_the_fields_and_the_saved_config(default_scene):
    import argparse

    import pytest

    from srvol.config import TrainConfig
    from srvol.data import load_scene
    from srvol.errors import SrvolError
    from srvol.train_cli import add_parser, build_config

    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers())
    scene = load_scene(default_scene)
    args = ["train", str(default_scene), "--out", "u"]
    assert build_config(scene, ap.parse_args(args)).fields.sdf_interpolation == "smoothstep"
    cfg = build_config(scene, ap.parse_args(args + ["--sdf-interpolation", "bspline"]))
    assert cfg.fields.sdf_interpolation == "bspline" and "(bspline)" in cfg.fields.parameter_summary()
    assert TrainConfig.from_json(cfg.to_json()) == cfg
    with pytest.raises(SrvolError, match="--sdf-interpolation"):
        build_config(scene, ap.parse_args(args + ["--sdf-interpolation", "bspline", "--preset", "paper"]))


def test_coarse_to_fine_opens_the_finer_levels_one_after_another():
    from srvol.encodings import level_window

    # 10 material levels, the 4 the specular head reads on from the start: halfway, 3 of 6 more are in
    assert level_window(10, 4, 0.0).tolist() == [1, 1, 1, 1, 0, 0, 0, 0, 0, 0]
    assert level_window(10, 4, 0.5).tolist() == [1, 1, 1, 1, 1, 1, 1, 0, 0, 0]
    assert level_window(10, 4, 0.25).tolist()[4:6] == [1.0, 0.5]  # the fifth in, the sixth fading in
    assert level_window(3, 1, 1.0).tolist() == [1, 1, 1]


def test_closed_levels_carry_no_detail_and_a_reloaded_model_has_them_all():
    fields = SceneFields(FieldConfig(sdf_levels=(8, 16, 32), mat_max_res=256), learn_intensity=False)
    with torch.no_grad():
        fields.mat_grid.table.uniform_(-1, 1)
        fields.sdf_net.grids.table.uniform_(-1, 1)
    x = torch.rand(500, 3) * 2 - 1
    fields.set_coarse_to_fine(0.0)
    coarse_feats = fields.mat_grid(x)
    assert float(coarse_feats[:, 2 * fields.cfg.spec_levels:].abs().max()) == 0.0  # fine material levels off
    assert float(fields.sdf_net.grids(x)[:, 4:].abs().max()) == 0.0  # only the 8^3 SDF grid speaks
    fields.set_coarse_to_fine(1.0)
    assert float(fields.mat_grid(x)[:, 2 * fields.cfg.spec_levels:].abs().max()) > 0.1
    # the window is training state, not a weight: a model loaded from its state dict reads every level
    fresh = SceneFields(fields.cfg, learn_intensity=False)
    fresh.load_state_dict(fields.state_dict())
    assert "mat_grid.level_weights" not in fields.state_dict()
    assert torch.equal(fresh.mat_grid.level_weights, torch.ones_like(fresh.mat_grid.level_weights))
