"""Surface anchors: stereo points from the training views, and the terms that hold the SDF to them (the pull)
and keep their lines of sight free (the free space)."""
import numpy as np
import pytest
import torch

from srvol.anchors import ANCHOR_TOLERANCE, FREE_SPACE_MARGIN, anchor_terms, find_anchors


def both(sdf_at, points, eyes, n, gen) -> float:
    """The pull and the free space at equal weights (``--anchors 1``)."""
    terms = anchor_terms(sdf_at, points, eyes, n, gen)
    return float(terms.pull + terms.free_space)


def solid_ball(x: torch.Tensor) -> torch.Tensor:
    """A ball of radius 0.5: closed on top, like a cup under a lid."""
    return x.norm(dim=-1) - 0.5


def ball_with_a_bowl(x: torch.Tensor) -> torch.Tensor:
    """The same ball with a bowl of radius 0.4 cut into its top (centre z 0.6): floor at z 0.2."""
    bowl = (x - x.new_tensor([0.0, 0.0, 0.6])).norm(dim=-1) - 0.4
    return torch.maximum(solid_ball(x), -bowl)


def test_a_point_on_the_bowls_floor_seen_from_above_costs_nothing_once_the_bowl_is_open():
    floor = torch.tensor([[0.0, 0.0, 0.2]])
    eye = torch.tensor([[0.0, 0.0, 2.6]])  # the view that saw it, straight above
    gen = torch.Generator().manual_seed(0)
    open_bowl = both(ball_with_a_bowl, floor, eye, 16, gen)
    lid = both(solid_ball, floor, eye, 16, gen)
    assert open_bowl < 1e-6
    # under the lid the point is 0.3 inside the surface (|d| 0.3, less the tolerance), and its line of
    # sight runs through solid from z 0.5 down to 0.2 + the margin: a third of its samples (from the
    # bound sphere at z 1), 0.125 deep on average
    assert lid == pytest.approx(0.3 - ANCHOR_TOLERANCE + 0.25 / 0.75 * 0.125, abs=0.02)


def test_a_point_within_a_stereo_points_error_of_the_surface_costs_nothing():
    # a point just under the surface, by less than the tolerance: its line of sight stops short of
    # it by the margin, above the surface, and the surface is not pulled to it
    eye = torch.tensor([[0.0, 0.0, 2.6]])
    gen = torch.Generator().manual_seed(0)
    just_under = torch.tensor([[0.0, 0.0, 0.5 - ANCHOR_TOLERANCE / 2]])
    assert both(solid_ball, just_under, eye, 8, gen) == 0.0
    # further under (but within the margin): only the distance beyond the tolerance counts
    under = torch.tensor([[0.0, 0.0, 0.5 - FREE_SPACE_MARGIN / 2]])
    expected = FREE_SPACE_MARGIN / 2 - ANCHOR_TOLERANCE
    assert both(solid_ball, under, eye, 8, gen) == pytest.approx(expected, abs=1e-6)


def test_the_free_space_opens_the_lid_and_never_pulls_the_surface_to_a_point():
    """The free space alone (--free-space): a lid in front of a point the view saw costs; a point a little off the surface,
    either side (a stereo point's error, up to the margin), costs nothing -- the surface stays where the
    photos put it."""
    eye = torch.tensor([[0.0, 0.0, 2.6]])
    gen = torch.Generator().manual_seed(0)
    floor = torch.tensor([[0.0, 0.0, 0.2]]).repeat(64, 1)  # 64 draws of the point, 4 samples each
    eyes = eye.repeat(64, 1)
    # a third of the line of sight lies in the lid, 0.125 deep on average (the test above)
    assert float(anchor_terms(solid_ball, floor, eyes, 64, gen).free_space) == pytest.approx(0.25 / 0.75 * 0.125,
                                                                                            abs=0.015)
    assert float(anchor_terms(ball_with_a_bowl, floor, eyes, 64, gen).free_space) < 1e-6
    for off in (-0.9, 0.9):  # in front of the surface or behind it, by 0.9 of the margin
        point = torch.tensor([[0.0, 0.0, 0.5 + off * FREE_SPACE_MARGIN]])
        terms = anchor_terms(solid_ball, point, eye, 8, gen)
        assert float(terms.free_space) == 0.0 and float(terms.pull) > 0.0


def test_stereo_points_of_a_textured_scene_lie_on_its_surface(textured_scene):
    from srvol.data import load_scene
    from srvol.synth.scenes import get_scene

    found = find_anchors(load_scene(textured_scene))
    assert len(found) >= 1000  # 5454 when written
    d = get_scene("bumpy").make_surface().sdf(torch.from_numpy(found.points)).abs()
    # an LR pixel's footprint on the object is 0.030 scene units here: a quarter of one for half the
    # points (0.0076 when written), and within one and a half for 99 %
    assert float(d.median()) < 0.01 and float((d < 0.045).float().mean()) > 0.98
    # each point's view centre is a camera of the scene, in front of which the point lies
    assert np.isfinite(found.eyes).all() and (np.linalg.norm(found.eyes, axis=-1) > 1.5).all()


def test_a_run_keeps_its_anchors_and_a_resumed_run_reads_them_back(textured_scene, tmp_path, monkeypatch):
    """Stereo runs once per run: its points are in RUN/anchors.npz, and --resume reads them there."""
    from dataclasses import replace

    import srvol.train as T
    from srvol.data import load_scene
    from srvol.presets import fast_config

    scene = load_scene(textured_scene)
    cfg = replace(fast_config(), iters=4, time_budget=0.0, checkpoint_every=2, stage2_fraction=0.0,
                  batch_in=64, batch_out=32, batch_eikonal=64, lambda_anchor=1.0)
    said = []
    T.train(scene, replace(cfg, iters=2), tmp_path / "run", progress=False, say=said.append)
    assert (tmp_path / "run" / T.ANCHORS_NAME).is_file()
    assert any(s.startswith("anchors: ") and "surface points by stereo" in s for s in said)

    def no_stereo(*_a, **_k):
        raise AssertionError("stereo ran again")

    monkeypatch.setattr(T, "find_anchors", no_stereo)
    summary = T.train(scene, cfg, tmp_path / "run", resume=True, progress=False, say=said.append)
    assert summary.iterations == 4


def test_the_anchor_terms_fade_to_zero_and_the_flags_are_checked(default_scene):
    import argparse
    from dataclasses import replace

    from srvol.data import load_scene
    from srvol.errors import SrvolError
    from srvol.losses import anchor_fade
    from srvol.presets import fast_config
    from srvol.train_cli import add_parser, build_config

    cfg = replace(fast_config(), lambda_free_space=2.0, anchor_fade=0.5)
    assert [anchor_fade(p, cfg) for p in (0.0, 0.25, 0.5, 0.9)] == [1.0, 0.5, 0.0, 0.0]
    assert anchor_fade(0.0, fast_config()) == 0.0  # off in the presets that do not ask for it
    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers())
    scene = load_scene(default_scene)
    args = ["train", str(default_scene), "--out", "u", "--preset", "fast"]
    asked = build_config(scene, ap.parse_args([*args, "--anchors", "0.5"]))
    assert (asked.lambda_anchor, asked.lambda_free_space) == (0.5, 0.5)  # both terms
    asked = build_config(scene, ap.parse_args([*args, "--anchors", "0.5", "--free-space", "2"]))
    assert (asked.lambda_anchor, asked.lambda_free_space) == (0.5, 2.0)
    auto = ["train", str(default_scene), "--out", "u"]
    assert (build_config(scene, ap.parse_args(auto)).lambda_free_space, build_config(
        scene, ap.parse_args([*auto, "--free-space", "1"])).lambda_free_space) == (0.0, 1.0)  # auto: off, asked: on
    for bad in ("-1", "nan", "1000"):
        with pytest.raises(SrvolError, match="--anchors"):
            build_config(scene, ap.parse_args([*args, "--anchors", bad]))
        with pytest.raises(SrvolError, match="--free-space"):
            build_config(scene, ap.parse_args([*args, "--free-space", bad]))
