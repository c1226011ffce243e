"""The one door into a trained model: ``load_model(run_dir)``.

A run folder (DESIGN.md section 5) holds config.json (plain JSON with a schema
version), model.pt (state dict) and checkpoints/. Consumers (eval, export,
relight) get a :class:`~srvol.types.FieldModel` and a :class:`RunInfo`; they
never import the training loop.
"""
from __future__ import annotations

import json
import os
import pickle
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from srvol.errors import SrvolError


@dataclass(frozen=True)
class RunInfo:
    """What a consumer needs to know about a trained run besides the fields.

    run_dir: the run folder; scene_dir: the scene it was trained on (None if unknown);
    light_intensity: the co-located light's intensity (given or learned), RGB;
    sr_factor: HR/LR ratio; hr_pixel_size: scene units covered by one HR pixel at the
    object's distance (median over training views) -- sizes marching cubes, faces and textures.
    """

    run_dir: Path
    scene_dir: Path | None
    light_intensity: tuple[float, float, float]
    sr_factor: int
    hr_pixel_size: float


CONFIG_VERSION = 1
CHECKPOINT_NAME = "last.pt"


def _atomic_torch_save(obj, path: Path) -> None:
    from srvol.images import atomic_path

    tmp = atomic_path(path)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def save_checkpoint(ckpt_dir: Path, fields, optimizers, state, gen_state) -> None:
    """Atomically write fields, optimiser states, the train state and the RNG state."""
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    _atomic_torch_save({"fields": fields.state_dict(), "optimizers": [o.state_dict() for o in optimizers],
                        "state": asdict(state), "generator": gen_state}, ckpt_dir / CHECKPOINT_NAME)


def load_checkpoint(ckpt_dir: Path, fields):
    """Restore ``fields`` in place; returns (TrainState, optimiser states, generator state) or None."""
    from srvol.train import TrainState

    path = ckpt_dir / CHECKPOINT_NAME
    if not path.is_file():
        return None
    try:
        ck = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:
        raise SrvolError(f"{path}: unreadable checkpoint ({e.__class__.__name__})") from None
    fields.load_state_dict(ck["fields"])
    st = TrainState(**ck["state"])
    if st.stage == 2:
        for p in fields.geometry_parameters():
            p.requires_grad_(False)
    return st, ck["optimizers"], ck["generator"]


def save_snapshot(snap_dir: Path, fields, step: int, seconds: float) -> Path:
    """Fields at one moment of training: snapshots/<step>_<seconds>s.pt (state dict)."""
    snap_dir.mkdir(parents=True, exist_ok=True)
    path = snap_dir / f"{step:07d}_{seconds:08.1f}s.pt"
    _atomic_torch_save(fields.state_dict(), path)
    return path


def write_model(run_dir: Path, fields) -> None:
    _atomic_torch_save(fields.state_dict(), run_dir / "model.pt")


def read_config(run_dir: Path) -> dict:
    path = Path(run_dir) / "config.json"
    if not path.is_file():
        raise SrvolError(f"{run_dir}: not a training run (no config.json)")
    try:
        cfg = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise SrvolError(f"{path}: malformed JSON ({e.msg})") from None
    if cfg.get("version") != CONFIG_VERSION:
        raise SrvolError(f"{path}: unsupported config version {cfg.get('version')!r} (expected {CONFIG_VERSION})")
    return cfg


def load_model(run_dir: str | Path, device: str = "cpu", weights: str | Path | None = None):
    """(fields, RunInfo) of a finished run: fields.sdf(x), fields.material(x) in eval mode.

    ``weights``: another state dict of the same run to load instead of model.pt (a snapshot).
    """
    from srvol.fields import FieldConfig, SceneFields

    run_dir = Path(run_dir)
    cfg = read_config(run_dir)
    model_path = Path(weights) if weights is not None else run_dir / "model.pt"
    if not model_path.is_file():
        ckpt = run_dir / "checkpoints" / CHECKPOINT_NAME
        if not ckpt.is_file():
            raise SrvolError(f"{run_dir}: no model.pt or checkpoint (training not finished?)")
    try:
        fields = SceneFields(FieldConfig.from_json(cfg["train"]["fields"]), learn_intensity=False)
        if model_path.is_file():
            state = torch.load(model_path, map_location="cpu", weights_only=True)
        else:
            state = torch.load(run_dir / "checkpoints" / CHECKPOINT_NAME, map_location="cpu",
                               weights_only=False)["fields"]
        fields.load_state_dict(state)
    except (KeyError, RuntimeError, OSError, pickle.UnpicklingError) as e:
        raise SrvolError(f"{model_path}: unreadable or mismatched model ({e.__class__.__name__})") from None
    fields = fields.to(device).eval()
    for p in fields.parameters():
        p.requires_grad_(False)
    sc = cfg["scene"]
    intensity = sc.get("light_intensity") or fields.intensity.tolist()
    info = RunInfo(run_dir=run_dir, scene_dir=Path(sc["path"]) if sc.get("path") else None,
                   light_intensity=tuple(float(v) for v in intensity), sr_factor=int(sc["sr_factor"]),
                   hr_pixel_size=float(sc["hr_pixel_size"]))
    return fields, info
