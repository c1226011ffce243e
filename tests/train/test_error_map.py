"""Stage 2's error map: draws where the error is, weights that keep every mean what a uniform draw
estimates, and the windows of steps it steadies."""
import math

import pytest
import torch

from srvol.data import load_scene
from srvol.error_map import CELL, ErrorMap
from srvol.pixels import PixelBank
from srvol.psf import PsfSampler, SRMode


@pytest.fixture(scope="module")
def bank(default_scene):
    return PixelBank(load_scene(default_scene), torch.device("cpu"))


def test_cells_are_4x4_blocks_of_one_view(bank):
    """Two in-mask pixels share a cell exactly when they are in the same view and the same 4x4 block."""
    m = ErrorMap(bank, 0.5)
    ij, view = bank.ij[bank.inside].long(), bank.view[bank.inside]
    key = view * 10_000 + (ij[:, 1] // CELL) * 100 + ij[:, 0] // CELL
    for a, b in ((0, 1), (0, 50), (3, 400), (10, len(key) - 1)):
        assert (m.cell_of[a] == m.cell_of[b]) == (key[a] == key[b])
    assert len(m) == len(torch.unique(key)) and int(m.count.sum()) == len(bank.inside)


def test_an_unmeasured_map_draws_uniformly(bank):
    m = ErrorMap(bank, 0.5)
    p = m.probabilities()
    assert torch.allclose(p, torch.full_like(p, 1.0 / len(p)))
    _, w = m.draw(100, torch.Generator().manual_seed(0))
    assert torch.allclose(w, torch.ones(100))


def test_half_the_draw_follows_the_error_and_the_weights_undo_it(bank):
    """One cell holds all of the error: it gets half the draws (plus its uniform share); the weights
    are N p back, so sum p * w * f is the plain mean of any f, and no weight exceeds 1 / (1 - share)."""
    m = ErrorMap(bank, 0.5)
    m.error.zero_()
    m.error[7] = 3.0
    p = m.probabilities()
    n = len(p)
    in_cell = m.cell_of == 7
    assert math.isclose(float(p[in_cell].sum()), 0.5 + 0.5 * float(in_cell.sum()) / n, rel_tol=1e-5)
    idx, w = m.draw(20_000, torch.Generator().manual_seed(1))
    assert abs(float(in_cell[idx].float().mean()) - float(p[in_cell].sum())) < 0.02
    assert torch.allclose(w, (1.0 / n) / p[idx])
    f = torch.rand(n, generator=torch.Generator().manual_seed(2))
    assert math.isclose(float((p * ((1.0 / n) / p) * f).sum()), float(f.mean()), rel_tol=1e-5)
    assert float(w.max()) <= 2.0 + 1e-6


def test_a_window_of_steps_is_steady_when_the_draw_follows_the_error(bank):
    """The case behind the map: 0.2 % of the pixels hold 80 % of the error (flash highlights left to
    fit). A 25-step window of 6 draws a step, drawn uniformly, misses them most of the time and its
    PSNR swings by over 10 dB; drawn by the map and weighted, it stays within 2 dB of the truth."""
    n = len(bank.inside)
    gen = torch.Generator().manual_seed(3)
    error = torch.full((n,), 1e-4)
    hot = torch.randperm(n, generator=gen)[: max(1, n // 500)]
    error[hot] = 0.8 * float(error.sum()) / (0.2 * len(hot))
    truth = -10 * math.log10(float(error.mean()))
    m = ErrorMap(bank, 0.5, cell=1)  # one pixel a cell: the map knows each pixel's error
    m.fill(error)

    def windows(draw) -> torch.Tensor:
        out = []
        for _ in range(200):
            idx, w = draw(150)
            out.append(-10 * math.log10(float((w * error[idx]).sum() / w.sum())))
        return torch.tensor(out)

    uniform = windows(lambda k: (torch.randint(n, (k,), generator=gen), torch.ones(k)))
    mapped = windows(lambda k: m.draw(k, gen))
    assert float(uniform.max() - uniform.min()) > 10.0
    assert float((mapped - truth).abs().max()) < 2.0


def test_fill_averages_a_cell_and_update_moves_it_towards_each_measurement(bank):
    m = ErrorMap(bank, 0.5)
    cell = m.cell_of[0]
    members = torch.nonzero(m.cell_of == cell).squeeze(-1)
    first = torch.zeros(len(bank.inside))
    first[members] = torch.arange(len(members), dtype=torch.float32)
    m.fill(first)
    assert float(m.error[cell]) == pytest.approx((len(members) - 1) / 2)
    assert float(m.error.sum()) == float(m.error[cell])  # no other cell has error
    from srvol.error_map import UPDATE_RATE

    before = float(m.error[cell])
    m.update(members[-1:], torch.tensor([0.5]))
    assert float(m.error[cell]) == pytest.approx((1 - UPDATE_RATE) * before + UPDATE_RATE * 0.5)


def test_patch_sums_add_the_pixels_a_patch_covers(bank):
    """A pixel value of 1 at one in-mask pixel: the patches that cover it are those centred up to 2
    pixels left/above and 1 right/below of it (a 4x4 patch starts 2 before its centre)."""
    from srvol.error_map import patch_sums

    k = int(bank.inside[len(bank.inside) // 2])
    values = torch.zeros(len(bank.colour))
    values[k] = 1.0
    sums = patch_sums(bank, values, 4)
    ij = bank.ij[bank.inside].long()
    same_view = bank.view[bank.inside] == bank.view[k]
    d = ij - bank.ij[k].long()
    covers = same_view & (d[:, 0] >= -1) & (d[:, 0] <= 2) & (d[:, 1] >= -1) & (d[:, 1] <= 2)
    assert torch.equal(sums > 0, covers) and float(sums.max()) == 1.0


def test_patches_drawn_by_the_map_carry_their_weights(bank):
    """Each pixel of a lattice patch carries its centre's weight, and the step's means use them."""
    from srvol.psf import GaussianPSF

    m = ErrorMap(bank, 0.5)
    m.error.zero_()
    m.error[0] = 1.0
    psf = PsfSampler(SRMode.GAUSSIAN, GaussianPSF(0.375, 4))
    batch = bank.sample_patches(5, 4, 0.5, psf, torch.Generator().manual_seed(4), m)
    assert batch.centre.shape == (5,) and batch.importance.shape == (5 * 16,)
    p = m.probabilities()
    expected = ((1.0 / len(p)) / p[batch.centre]).repeat_interleave(16)
    assert torch.allclose(batch.importance, expected)
    assert torch.allclose(batch.pixel_weight, batch.mask * expected)
    assert torch.allclose(batch.groups(1, 3).importance, expected[16:48])


def test_a_run_with_the_map_trains_stage_2_from_it(default_scene, tmp_path):
    """auto draws half of stage 2 by the map, the paper and fast presets uniformly; ``--stage2-importance``
    sets the share. Stage 2 measures the map when it begins, says so, and trains from
    it (the log's stage-2 lines are finite); the flag refuses a share outside 0..0.9 in one line."""
    import argparse
    import json
    from dataclasses import replace

    from srvol.errors import SrvolError
    from srvol.presets import auto_config, fast_config, paper_config
    from srvol.train import train
    from srvol.train_cli import add_parser, build_config

    scene = load_scene(default_scene)
    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers())
    assert auto_config(scene, "gaussian", 60.0).stage2_importance == 0.5  # auto's; the paper draws uniformly
    assert auto_config(scene, "none", 60.0).stage2_importance == 0.5  # noSR is drawn the same way
    assert fast_config().stage2_importance == paper_config().stage2_importance == 0.0
    off = build_config(scene, ap.parse_args(["train", str(default_scene), "--out", "u", "--stage2-importance", "0"]))
    assert off.stage2_importance == 0.0
    cfg = build_config(scene, ap.parse_args(["train", str(default_scene), "--out", "u", "--stage2-importance", "0.8"]))
    assert cfg.stage2_importance == 0.8
    for bad in ("1", "-0.1", "nan"):
        with pytest.raises(SrvolError, match="--stage2-importance"):
            build_config(scene, ap.parse_args(["train", str(default_scene), "--out", "u", "--stage2-importance", bad]))
    said = []
    tiny = replace(cfg, iters=16, time_budget=0.0, checkpoint_every=10_000, log_every=2, batch_in=96, batch_out=64,
                   batch_eikonal=128, batch_stage2=128, stage2_fraction=0.5, stage2_importance=0.5)
    train(scene, tiny, tmp_path / "run", progress=False, say=said.append)
    assert any(s.startswith("stage 2 error map:") for s in said)
    lines = [json.loads(x) for x in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert [r["stage"] for r in lines][-1] == 2 and all(math.isfinite(r["psnr"]) for r in lines)
