"""A run folder somebody sends you is data, never code.

Every command that opens a run reads its ``.pt`` files weights-only: a crafted pickle that would
create a file when unpickled is refused with one error line, and the file is never created. Runs
saved before the JSON checkpoint record existed still load.
"""
from __future__ import annotations

import json
import pathlib
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from srvol.checkpoint import TrainState, load_checkpoint, load_model, save_checkpoint
from srvol.cli import main
from srvol.config import RunConfig, SceneRecord, read_run_config, write_run_config
from srvol.presets import fast_config
from srvol.fields import FieldConfig, SceneFields
from srvol.psf import GaussianPSF

TINY_FIELDS = FieldConfig(sdf_levels=(4, 4, 8), mat_levels=2, mat_min_res=4, mat_max_res=8, mat_table_log2=8,
                          sdf_hidden=8, mat_hidden=8)


class CreatesAFile:
    """Unpickling this calls ``Path(target).touch()``: what a malicious run folder would do."""

    def __init__(self, target: Path):
        self.target = target

    def __reduce__(self):
        return pathlib.Path.touch, (pathlib.Path(self.target),)


def _fields() -> SceneFields:
    torch.manual_seed(0)
    return SceneFields(TINY_FIELDS, learn_intensity=False)


def _run(root: Path, scene_dir: Path | None) -> Path:
    """A finished run of tiny fields: config.json and model.pt."""
    run = root / "run"
    run.mkdir()
    train = replace(fast_config(), fields=TINY_FIELDS)
    write_run_config(run, RunConfig(train=train, scene=SceneRecord(
        path=scene_dir, psf=GaussianPSF(0.5, 2), hr_pixel_size=0.01, light_intensity=(2.0, 2.0, 2.0))))
    torch.save(_fields().state_dict(), run / "model.pt")
    return run


def _poison(run: Path, marker: Path, where: str) -> None:
    """Replace the run's weights by a crafted pickle: model.pt itself, or (model.pt gone) the
    checkpoint a resume or an unfinished run falls back to, old layout or new."""
    evil = {"fields": CreatesAFile(marker), "state": {"step": 1}}
    if where == "model":
        torch.save(evil, run / "model.pt")
        return
    (run / "model.pt").unlink()
    ckpt = run / "checkpoints"
    ckpt.mkdir()
    if where == "legacy-checkpoint":
        torch.save(evil, ckpt / "last.pt")
    else:
        torch.save(evil, ckpt / "weights_00000001.pt")
        (ckpt / "last.json").write_text(json.dumps({"format": "srvol-checkpoint/2", "weights": "weights_00000001.pt",
                                                    "state": {"step": 1, "stage": 1}}))


COMMANDS = {
    "eval": lambda run, scene, out: ["eval", str(run), "--scene", str(scene), "--no-relit"],
    "relight": lambda run, scene, out: ["relight", str(run), "--light-pos", "1.5,0,2", "--resolution", "16x12",
                                        "--out", str(out / "relit.png")],
    "export": lambda run, scene, out: ["export", str(run), "--format", "obj", "--out", str(out / "asset")],
    "report": lambda run, scene, out: ["report", str(run), "--out", str(out / "report.html")],
    "train --resume": lambda run, scene, out: ["train", str(scene), "--out", str(run), "--resume", "--quiet"],
}


@pytest.mark.parametrize("where", ["model", "legacy-checkpoint", "checkpoint"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_crafted_pickle_in_a_run_runs_no_code(command, where, tiny_scene, tmp_path, capsys):
    run = _run(tmp_path, tiny_scene)
    marker = tmp_path / "pwned"
    _poison(run, marker, where)
    out = tmp_path / "out"
    out.mkdir()
    rc = main(COMMANDS[command](run, tiny_scene, out))
    err = capsys.readouterr().err
    assert not marker.exists(), f"{command} ran the pickle's code"
    if command == "report":  # the report reads config.json and pictures, never weights
        assert rc == 0
        return
    if where == "model" and command == "train --resume":  # resume reads the checkpoint, and there is none
        assert rc == 2 and "nothing to resume" in err
        return
    assert rc == 2 and err.count("\n") == 1 and err.startswith("srvol: error:"), err
    assert "refused: not a plain weights file" in err


def test_load_model_refuses_the_pickle_directly(tmp_path):
    run = _run(tmp_path, None)
    _poison(run, tmp_path / "pwned", "model")
    with pytest.raises(Exception, match="refused"):
        load_model(run)
    assert not (tmp_path / "pwned").exists()


def test_a_checkpoint_saved_before_the_json_record_still_loads(tmp_path):
    """The old layout: one checkpoints/last.pt holding fields, optimiser states, the state dict and the
    RNG state. Its contents are plain data, so it loads weights-only: resume and load_model work."""
    run = _run(tmp_path, None)
    fields = _fields()
    with torch.no_grad():
        next(fields.parameters()).add_(0.25)  # differs from model.pt's fields
    opt = torch.optim.Adam(fields.parameters(), lr=1e-3)
    (run / "checkpoints").mkdir()
    torch.save({"fields": fields.state_dict(), "optimizers": [opt.state_dict()],
                "state": {"step": 40, "stage": 2, "elapsed": 12.5, "lr_scale": 1.0, "rollbacks": 0},
                "generator": torch.Generator().manual_seed(0).get_state()}, run / "checkpoints" / "last.pt")
    restored = _fields()
    ck = load_checkpoint(run / "checkpoints", restored)
    assert ck.state == TrainState(step=40, stage=2, elapsed=12.5)
    assert all(torch.equal(a, b) for a, b in zip(restored.state_dict().values(), fields.state_dict().values()))
    assert not any(p.requires_grad for p in restored.geometry_parameters())  # stage 2: geometry frozen
    (run / "model.pt").unlink()  # an unfinished run: load_model falls back on the checkpoint
    model, info = load_model(run)
    assert torch.equal(next(model.parameters()), next(fields.parameters()))


def test_a_new_checkpoint_is_weights_plus_a_json_record_naming_them(tmp_path):
    """save_checkpoint writes weights_<step>.pt, then last.json (the commit point), then drops older
    weights; the JSON holds everything that is not a tensor."""
    fields = _fields()
    opt = torch.optim.Adam(fields.parameters(), lr=1e-3)
    gen = torch.Generator().manual_seed(0)
    ckpt = tmp_path / "checkpoints"
    save_checkpoint(ckpt, fields, [opt], TrainState(step=4), gen.get_state())
    save_checkpoint(ckpt, fields, [opt], TrainState(step=8, elapsed=3.0), gen.get_state())
    assert sorted(p.name for p in ckpt.iterdir()) == ["last.json", "weights_00000008.pt"]
    record = json.loads((ckpt / "last.json").read_text())
    assert record["weights"] == "weights_00000008.pt" and record["state"]["step"] == 8
    torch.load(ckpt / "weights_00000008.pt", weights_only=True)  # plain data
    assert load_checkpoint(ckpt, _fields()).state == TrainState(step=8, elapsed=3.0)


def test_config_json_round_trips_through_the_typed_pair(tmp_path):
    run = _run(tmp_path, tmp_path / "scene")
    config = read_run_config(run)
    assert config.train.fields == TINY_FIELDS
    assert config.scene.psf == GaussianPSF(0.5, 2) and config.scene.psf.sigma_hr_px == 1.0
    assert config.scene.path == tmp_path / "scene" and config.scene.light_intensity == (2.0, 2.0, 2.0)
    write_run_config(tmp_path, config)
    assert read_run_config(tmp_path) == config
    raw = json.loads((run / "config.json").read_text())
    del raw["scene"]["hr_pixel_size"]
    (run / "config.json").write_text(json.dumps(raw))
    with pytest.raises(Exception, match="malformed config \\(missing 'hr_pixel_size'\\)"):
        read_run_config(run)
