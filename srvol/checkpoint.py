"""The one door into a trained model (``load_model(run_dir)``), and training's checkpoints.

A run folder (DESIGN.md section 5) holds config.json (:mod:`srvol.config`), model.pt (the
fields' state dict) and checkpoints/. A run folder somebody sends you is data, never code:
every ``.pt`` is read with ``torch.load(weights_only=True)`` (tensors, numbers, strings, lists,
dicts -- nothing that runs when unpickled), and whatever is not a tensor is JSON beside it.

checkpoints/ holds ``weights_<step>.pt`` (fields, optimiser states, the RNG state) and
``last.json`` (the :class:`TrainState` and the name of its weights file). The weights are
written first, then last.json (the commit point), then older weights are removed: a kill at
any moment leaves a last.json that names complete weights. Runs saved before this layout
(one ``last.pt`` holding the state too) still load, weights-only.

Consumers (eval, export, relight) get the fields and a :class:`RunInfo`; they never import
the training loop.
"""
from __future__ import annotations

import json
import os
import pickle
from dataclasses import asdict, dataclass, fields as dataclass_fields
from pathlib import Path

import torch

from srvol.config import read_run_config
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


@dataclass
class TrainState:
    """Where training is: the step, the stage (1 geometry + BRDF, 2 BRDF only), seconds trained,
    the learning-rate scale (halved by each rollback after a non-finite loss), the rollbacks and
    the seconds spent compiling."""

    step: int = 0
    stage: int = 1
    elapsed: float = 0.0
    lr_scale: float = 1.0
    rollbacks: int = 0
    paused: float = 0.0
    """Seconds of ``elapsed`` the schedule does not count: compiling the field queries (they count in
    the budget, but no step is taken while the beta cap and learning rates would move on)."""

    @staticmethod
    def from_json(d: dict) -> "TrainState":
        known = {f.name for f in dataclass_fields(TrainState)}
        return TrainState(**{k: v for k, v in d.items() if k in known})


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint as read back: the train state and the saved tensors (optimiser states and the
    RNG state are restored by the loop; the fields are restored in place by :func:`load_checkpoint`)."""

    state: TrainState
    optimizer_states: list
    generator_state: torch.Tensor


STATE_NAME = "last.json"
LEGACY_NAME = "last.pt"
CHECKPOINT_FORMAT = "srvol-checkpoint/2"


def load_weights(path: Path):
    """``torch.load`` of a weights file, weights only: a file that would run code when unpickled is
    refused with one error line, and nothing of it runs."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise SrvolError(f"{path}: refused: not a plain weights file (loading it would run code; srvol "
                         "reads weights only)") from None
    except (RuntimeError, OSError, EOFError, ValueError) as e:
        raise SrvolError(f"{path}: unreadable weights file ({e.__class__.__name__})") from None


def _atomic_torch_save(obj, path: Path) -> None:
    from srvol.atomic import atomic_path

    tmp = atomic_path(path)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def save_checkpoint(ckpt_dir: Path, fields, optimizers, state: TrainState, gen_state: torch.Tensor,
                    capture=None) -> None:
    """Atomically write fields, optimiser states, the RNG state and the capture terms (if any),
    then the train state as JSON."""
    from srvol.atomic import atomic_write_text

    ckpt_dir.mkdir(parents=True, exist_ok=True)
    name = f"weights_{state.step:08d}.pt"
    _atomic_torch_save({"fields": fields.state_dict(), "optimizers": [o.state_dict() for o in optimizers],
                        "generator": gen_state, **({"capture": capture.state_dict()} if capture is not None else {})},
                       ckpt_dir / name)
    atomic_write_text(ckpt_dir / STATE_NAME, json.dumps({"format": CHECKPOINT_FORMAT, "weights": name,
                                                          "state": asdict(state)}, indent=1))
    for old in ckpt_dir.glob("weights_*.pt"):
        if old.name != name:
            old.unlink(missing_ok=True)
    (ckpt_dir / LEGACY_NAME).unlink(missing_ok=True)


def _read_checkpoint(ckpt_dir: Path) -> tuple[TrainState, dict] | None:
    """(train state, saved tensors) of the last checkpoint, None when there is none."""
    state_path = ckpt_dir / STATE_NAME
    if state_path.is_file():
        try:
            record = json.loads(state_path.read_text())
            weights = ckpt_dir / Path(record["weights"]).name
            state = TrainState.from_json(record["state"])
        except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as e:
            raise SrvolError(f"{state_path}: malformed checkpoint record ({e.__class__.__name__})") from None
        if not weights.is_file():
            raise SrvolError(f"{state_path}: names {weights.name}, which is missing")
        return state, load_weights(weights)
    legacy = ckpt_dir / LEGACY_NAME
    if legacy.is_file():  # saved before the JSON record existed: the state sits in the weights file
        saved = load_weights(legacy)
        try:
            return TrainState.from_json(saved["state"]), saved
        except (KeyError, TypeError):
            raise SrvolError(f"{legacy}: not a srvol checkpoint (no train state)") from None
    return None


def freeze_geometry(fields, capture=None, keep_sdf: bool = False) -> None:
    """Stage 2: the SDF, beta and (with capture terms) the refined poses stop learning; with
    ``keep_sdf`` (``TrainConfig.stage2_geometry_lr``) the SDF goes on learning."""
    frozen = [fields.log_beta] if keep_sdf else fields.geometry_parameters()
    for p in frozen + (capture.pose_parameters() if capture is not None else []):
        p.requires_grad_(False)


def load_checkpoint(ckpt_dir: Path, fields, capture=None, keep_sdf: bool = False) -> Checkpoint | None:
    """Restore ``fields`` (and the ``capture`` terms, when the run has them) in place from the last
    checkpoint; None when there is none."""
    read = _read_checkpoint(ckpt_dir)
    if read is None:
        return None
    state, saved = read
    try:
        fields.load_state_dict(saved["fields"])
        if capture is not None:
            capture.load_state_dict(saved["capture"])
        ck = Checkpoint(state=state, optimizer_states=saved["optimizers"], generator_state=saved["generator"])
    except (KeyError, RuntimeError, TypeError) as e:
        raise SrvolError(f"{ckpt_dir}: checkpoint does not match the run's fields ({e.__class__.__name__})") from None
    if state.stage == 2:
        freeze_geometry(fields, capture, keep_sdf)
    return ck


def save_snapshot(snap_dir: Path, fields, step: int, seconds: float) -> Path:
    """Fields at one moment of training: snapshots/<step>_<seconds>s.pt (state dict)."""
    snap_dir.mkdir(parents=True, exist_ok=True)
    path = snap_dir / f"{step:07d}_{seconds:08.1f}s.pt"
    _atomic_torch_save(fields.state_dict(), path)
    return path


def write_model(run_dir: Path, fields) -> None:
    _atomic_torch_save(fields.state_dict(), run_dir / "model.pt")


def load_model(run_dir: str | Path, device: str = "cpu", weights: str | Path | None = None):
    """(fields, RunInfo) of a finished run: fields.sdf(x), fields.material(x) in eval mode.

    ``weights``: another state dict of the same run to load instead of model.pt (a snapshot).
    Without model.pt (training not finished) the last checkpoint's fields are used.
    """
    from srvol.fields import SceneFields

    run_dir = Path(run_dir)
    config = read_run_config(run_dir)
    model_path = Path(weights) if weights is not None else run_dir / "model.pt"
    fields = SceneFields(config.train.fields, learn_intensity=False)
    if model_path.is_file():
        try:
            fields.load_state_dict(load_weights(model_path))
        except (KeyError, RuntimeError, TypeError, AttributeError) as e:
            raise SrvolError(f"{model_path}: unreadable or mismatched model ({e.__class__.__name__})") from None
    elif load_checkpoint(run_dir / "checkpoints", fields) is None:
        raise SrvolError(f"{run_dir}: no model.pt or checkpoint (training not finished?)")
    fields = fields.to(device).eval()
    for p in fields.parameters():
        p.requires_grad_(False)
    sc = config.scene
    intensity = sc.light_intensity or tuple(fields.intensity.tolist())
    info = RunInfo(run_dir=run_dir, scene_dir=sc.path, light_intensity=tuple(float(v) for v in intensity),
                   sr_factor=sc.psf.sr, hr_pixel_size=sc.hr_pixel_size)
    return fields, info
