"""SuperRVol training: stage 1 learns geometry and BRDF, stage 2 refines the BRDF (``stage2_geometry_lr``: the SDF too).

What a run is (:mod:`srvol.config`), the loss (:mod:`srvol.losses`), the pixels and their PSF rays
(:mod:`srvol.pixels`) and checkpoints (:mod:`srvol.checkpoint`) live in their own modules; this one
holds the optimisers, the learning-rate schedule and the loop with its time budget.
"""
from __future__ import annotations

import json
import time
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path

import torch
from tqdm import tqdm

from srvol.anchors import AnchorPoints, Anchors, find_anchors
from srvol.atomic import atomic_write_text
from srvol.capture.terms import CaptureTerms
from srvol.checkpoint import TrainState, freeze_geometry, load_checkpoint, save_checkpoint, save_snapshot, write_model
from srvol.config import TrainConfig, rays_per_step, sampler_of_stage
from srvol.data import Scene
from srvol.distributed import SINGLE, Shard
from srvol.error_map import CELL, ErrorMap
from srvol.errors import SrvolError
from srvol.fields import BETA_INIT, SceneFields
from srvol.losses import (choose_stage2_samples, compute_loss, faithful_stage2_sampler, measure_error_map,
                          probe_pixels, probe_psnr, psnr_of)
from srvol.pixels import PixelBank, PixelBatch
from srvol.psf import PsfSampler, SRMode

POSE_LR = 2e-4
"""Adam's rate for the pose refinement (radians and scene units per step, before the decay): 0.01 deg
a step, so that a pose moves a fraction of a degree over a run while the shape forms."""

CAPTURE_TERMS_NAME = "capture_terms.json"
"""The learned capture terms of a run that has them (per-photo gains, flash offset, vignetting, ambient)."""


# ----------------------------------------------------------------------------- optimisation

def make_optimizers(fields: SceneFields, cfg: TrainConfig, stage: int,
                    capture: CaptureTerms | None = None) -> list[torch.optim.Optimizer]:
    albedo_p, spec_p, table_p = fields.material_groups()
    opts: list[torch.optim.Optimizer] = []
    groups = []
    if cfg.trains_geometry(stage):
        share = 1.0 if stage == 1 else cfg.stage2_geometry_lr
        lr_grid, lr_head = cfg.lr_grid * share, cfg.lr * share
        if cfg.fields.kind == "grid":
            grid_p = [fields.sdf_net.grids.table]
            head_p = list(fields.sdf_net.head.parameters())
            groups += [{"params": grid_p, "lr": lr_grid, "base_lr": lr_grid, "geometry": True},
                       {"params": head_p, "lr": lr_head, "base_lr": lr_head, "geometry": True}]
        else:
            groups.append({"params": list(fields.sdf_net.parameters()), "lr": lr_head, "base_lr": lr_head,
                           "geometry": True})
    if stage == 1:
        groups.append({"params": [fields.log_beta], "lr": cfg.lr_beta, "base_lr": cfg.lr_beta})
    groups += [{"params": albedo_p, "lr": cfg.lr, "base_lr": cfg.lr},
               {"params": spec_p, "lr": cfg.lr_spec, "base_lr": cfg.lr_spec}]
    if table_p:
        groups.append({"params": table_p, "lr": cfg.lr_grid, "base_lr": cfg.lr_grid})
    if fields.log_intensity.requires_grad:
        groups.append({"params": [fields.log_intensity], "lr": cfg.lr, "base_lr": cfg.lr})
    if capture is not None:
        # both stages: exposure, vignetting and ambient are part of the colour the BRDF is fitted to
        pose_p = capture.pose_parameters()
        capture_p = [p for p in capture.parameters() if p.requires_grad and all(p is not q for q in pose_p)]
        if capture_p:
            groups.append({"params": capture_p, "lr": cfg.lr, "base_lr": cfg.lr})
        if pose_p and stage == 1:  # the poses settle with the geometry; stage 2 freezes both
            groups.append({"params": pose_p, "lr": POSE_LR, "base_lr": POSE_LR})
    # fused Adam: one kernel over all parameters (large grids), ~7x faster than the loop on CPU
    opts.append(torch.optim.Adam(groups, betas=(0.9, 0.99), eps=1e-15, fused=True))
    return opts


def restore_optimizers(fields: SceneFields, cfg: TrainConfig, ck,
                       capture: CaptureTerms | None = None) -> list[torch.optim.Optimizer]:
    """The optimisers of the checkpoint's stage with their saved states."""
    opts = make_optimizers(fields, cfg, ck.state.stage, capture)
    for o, saved in zip(opts, ck.optimizer_states):
        o.load_state_dict(saved)
    return opts


def geometry_tail(progress: float, cfg: TrainConfig) -> float:
    """The extra factor on the geometry's learning rates at ``progress`` of the run: 1 over the first
    half of stage 1, then falling geometrically to ``cfg.geometry_lr_tail`` at stage 1's end."""
    stage1_end = max(1.0 - cfg.stage2_fraction, 1e-9)
    second_half = min(max(progress / stage1_end * 2.0 - 1.0, 0.0), 1.0)
    return cfg.geometry_lr_tail ** second_half


def set_learning_rate(opts, progress: float, cfg: TrainConfig, scale: float) -> None:
    """Exponential decay from base_lr to base_lr * lr_final / lr over training; the geometry's groups
    also take :func:`geometry_tail`."""
    decay = (cfg.lr_final / cfg.lr) ** min(max(progress, 0.0), 1.0)
    tail = geometry_tail(progress, cfg)
    for opt in opts:
        for g in opt.param_groups:
            g["lr"] = g["base_lr"] * decay * scale * (tail if g.get("geometry") else 1.0)


def take_step(opts: list[torch.optim.Optimizer], loss: torch.Tensor, shard: Shard = SINGLE) -> None:
    """One optimiser step on ``loss`` (data-parallel: on the gradients summed over the ranks)."""
    for o in opts:
        o.zero_grad(set_to_none=True)
    loss.backward()
    shard.sum_gradients([p for o in opts for g in o.param_groups for p in g["params"]])
    for o in opts:
        o.step()


def warm_up_compiled(fields: SceneFields, bank: PixelBank, cfg: TrainConfig, psf: PsfSampler, stage: int,
                     intensity: torch.Tensor, capture: CaptureTerms | None, probe: PixelBatch | None) -> float:
    """Seconds spent compiling ``stage``'s queries now: one step's loss and backward (gradients
    dropped, the run's random draws untouched) and the probe's render. Without compiled queries, 0.

    torch.compile compiles on first use (~65 s on a cold cache as stage 1 begins, ~30 s at stage 2);
    inside the loop that time would pass on the schedule's clock with no step taken -- on stool the
    beta cap fell to a third before step 200 and the run lost 5 dB (suite_tuning.md)."""
    if not cfg.compile:
        return 0.0
    t0 = time.time()
    device = bank.device
    with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        gen = torch.Generator().manual_seed(cfg.seed + 104729)
        compute_loss(fields, bank, cfg, psf, stage, gen, intensity, 0.0, capture).total.backward()
        if probe is not None:
            probe_psnr(fields, bank, probe, cfg, stage, intensity, capture)
    fields.zero_grad(set_to_none=True)
    if capture is not None:
        capture.zero_grad(set_to_none=True)
    return time.time() - t0


def check_not_collapsed(fields: SceneFields, device) -> str | None:
    """A one-line reason when the SDF has no surface (all positive or all negative) in the unit sphere."""
    with torch.no_grad():
        g = torch.linspace(-0.95, 0.95, 24, device=device)
        pts = torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        pts = pts[pts.norm(dim=-1) < 0.95]
        d = fields.sdf(pts)
    if not torch.isfinite(d).all():
        return "the SDF became non-finite"
    if (d > 0).all():
        return "the SDF collapsed: no surface inside the unit sphere (everything is empty)"
    if (d < 0).all():
        return "the SDF collapsed: the unit sphere is entirely inside the object"
    return None


# ----------------------------------------------------------------------------- the loop

def beta_cap(progress: float, anneal: float, end: float) -> float:
    """The upper bound on beta at ``progress`` of the run: from its start (BETA_INIT) to ``end``
    geometrically over the first ``anneal`` of it, then ``end``."""
    return BETA_INIT * (end / BETA_INIT) ** min(max(progress, 0.0) / anneal, 1.0)


def recent_psnr(recent: deque[tuple[float, float]]) -> float:
    """Train PSNR over the pixels of the last ``log_every`` steps (the logged figure): one step of
    stage 2 holds a few 4x4-pixel lattice patches, so a single step's PSNR swings by several dB
    with where its patches fall; over 25 steps the estimate is steady. nan before any step."""
    pixels = sum(px for _, px in recent)
    return psnr_of(sum(se for se, _ in recent), pixels) if pixels > 0 else float("nan")


def settle_stage2_sampler(fields: SceneFields, bank: PixelBank, probe, cfg: TrainConfig, intensity,
                          capture: CaptureTerms | None, shard: Shard, say) -> TrainConfig:
    """``cfg`` with the stage-2 sampler :func:`choose_stage2_samples` picks on the geometry as it stands
    (rank 0 measures; every rank takes its answer)."""
    choice = choose_stage2_samples(fields, bank, probe, cfg, intensity, capture) if shard.is_main else None
    widened, = shard.agree(1.0 if choice is not None and choice.widened else 0.0)
    if choice is not None and choice.measured:
        cheap, full = sampler_of_stage(cfg, 2), sampler_of_stage(cfg, 1)
        say(f"stage 2 samples: {cheap.n_coarse} + {cheap.gradient_samples} per ray render the probe pixels at "
            f"{choice.probe_cheap:.2f} dB, stage 1's {full.n_coarse} + {full.gradient_samples} at "
            f"{choice.probe_stage1:.2f} -- " + (f"widened to {choice.sampler.n_coarse} + "
                                                f"{choice.sampler.gradient_samples}" if widened else "kept"))
    return replace(cfg, stage2_sampler=faithful_stage2_sampler(cfg)) if widened else cfg


ANCHORS_NAME = "anchors.npz"
"""The run's anchor points (:mod:`srvol.anchors`): found once, read back on --resume."""


def surface_anchors(scene: Scene, cfg: TrainConfig, stage: int, run_dir: Path, device, say) -> AnchorPoints | None:
    """The anchors of ``cfg.lambda_anchor`` and ``cfg.lambda_free_space`` (:mod:`srvol.anchors`) on
    ``device``: None when both terms are off or stage 1 is over. Found by stereo on the training views
    once per run (every rank finds the same points: no randomness) and kept in the run folder."""
    if not cfg.uses_stereo() or stage != 1:
        return None
    path = run_dir / ANCHORS_NAME
    if path.is_file():
        found = Anchors.load(path)
    else:
        t0 = time.time()
        found = find_anchors(scene, cfg.sampler.bound)
        say(f"anchors: {len(found)} surface points by stereo between neighbouring training views "
            f"({time.time() - t0:.0f} s, counted in the budget)" + ("" if len(found) else " -- the term is off"))
        found.save(path)
    return AnchorPoints.of(found, device) if len(found) else None


def stage2_error_map(fields: SceneFields, bank: PixelBank, cfg: TrainConfig, psf: PsfSampler, intensity,
                     capture: CaptureTerms | None, shard: Shard, say) -> ErrorMap | None:
    """Stage 2's error map (:mod:`srvol.error_map`) on the geometry as it stands; None when
    ``cfg.stage2_importance`` is 0. Every rank of a data-parallel run holds rank 0's map and writes
    the whole step's errors into it, so all draw the same patches."""
    if cfg.stage2_importance <= 0:
        return None
    t0 = time.time()
    error_map = measure_error_map(fields, bank, cfg, psf, intensity, capture)
    error_map.error = shard.broadcast(error_map.error)
    say(f"stage 2 error map: {len(error_map)} cells of {CELL}x{CELL} LR pixels measured in {time.time() - t0:.1f} s; "
        f"{cfg.stage2_importance:.0%} of the pixels drawn by it")
    return error_map


def samples_in_words(cfg: TrainConfig) -> str:
    """Stage 2's locating + gradient samples per ray, e.g. "16 + 4"."""
    s = sampler_of_stage(cfg, 2)
    return f"{s.n_coarse} + {s.gradient_samples}"


@dataclass(frozen=True)
class TrainSummary:
    iterations: int
    train_seconds: float
    final_psnr: float
    rollbacks: int
    stage2_samples: str = ""
    """Stage 2's locating + gradient samples per ray as trained ("" without a stage 2)."""


def train(scene: Scene, cfg: TrainConfig, run_dir: Path, resume: bool = False, progress: bool = True,
          say=print, shard: Shard = SINGLE) -> TrainSummary:
    """Train on ``scene`` into ``run_dir`` (config.json, checkpoints/, log.jsonl, model.pt).
    ``shard``: this process's rank of a data-parallel run (rank 0 alone writes and speaks)."""
    main = shard.is_main
    say = say if main else (lambda *_: None)
    device = torch.device(cfg.device)
    run_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    learn_I = scene.info.light_intensity is None
    fields = SceneFields(cfg.fields, learn_intensity=learn_I).to(device)
    if cfg.compile:
        fields.compile_queries()
    fixed_I = None if learn_I else torch.tensor(scene.info.light_intensity, dtype=torch.float32, device=device)

    def light_intensity() -> torch.Tensor:
        """The flash's intensity: the scene's, or the one training learns."""
        return fixed_I if fixed_I is not None else fields.intensity

    bank = PixelBank(scene, device)
    capture = (CaptureTerms(len(scene.train), bank.camera_of_view, cfg.capture).to(device)
               if cfg.capture is not None else None)
    state = TrainState()
    ckpt_dir = run_dir / "checkpoints"
    opts = make_optimizers(fields, cfg, 1, capture)
    if resume:
        ck = load_checkpoint(ckpt_dir, fields, capture, cfg.trains_geometry(2))
        if ck is None:
            raise SrvolError(f"{ckpt_dir}: nothing to resume (no checkpoint)")
        state = ck.state
        opts = restore_optimizers(fields, cfg, ck, capture)
        gen.set_state(ck.generator_state)
        say(f"resuming at step {state.step} (stage {state.stage}, {state.elapsed:.0f} s trained)")
    psf = PsfSampler(SRMode(cfg.sr), scene.info.psf)
    t_setup = time.time()  # the stereo's time and a resumed stage 2's map are the run's (stereo: 20-90 s)
    anchors = surface_anchors(scene, cfg, state.stage, run_dir, device, say)
    probe = probe_pixels(bank, cfg, psf) if main else None
    error_map = None
    if state.stage == 2:  # measured again on the geometry as it stands (frozen: as when stage 2 began)
        cfg = settle_stage2_sampler(fields, bank, probe, cfg, light_intensity(), capture, shard, say)
        error_map = stage2_error_map(fields, bank, cfg, psf, light_intensity(), capture, shard, say)
    state.paused += warm_up_compiled(fields, bank, cfg, psf, state.stage, light_intensity(), capture, probe)
    budget, = shard.agree(cfg.time_budget if cfg.iters == 0 else 0.0)  # rank 0's: one budget binds all ranks
    stage2_at = int(cfg.iters * (1 - cfg.stage2_fraction)) if cfg.iters else None
    log_path = run_dir / "log.jsonl"
    t_start = t_setup - state.elapsed
    bar = tqdm(total=cfg.iters or int(budget), disable=not (progress and main), unit="it" if cfg.iters else "s",
               desc="train", initial=state.step if cfg.iters else int(state.elapsed))
    recent: deque[tuple[float, float]] = deque(maxlen=cfg.log_every)  # (squared error, pixels) of the last steps
    last_good_step = state.step
    snaps_done = len(list((run_dir / "snapshots").glob("*.pt"))) if cfg.snapshots else 0
    step_seconds, stage2_skipped = 0.0, False  # the last step's duration: the estimate of the next one's
    while True:
        # rank 0's clock for every rank: all agree when stage 2 starts and when the budget ends
        elapsed, step_seconds = shard.agree(time.time() - t_start, step_seconds)
        if cfg.iters:
            if state.step >= cfg.iters:
                break
            progress_frac = state.step / cfg.iters
            want_stage = 2 if state.step >= stage2_at and cfg.stage2_fraction > 0 else 1
        else:
            paused, = shard.agree(state.paused)
            progress_frac = max(0.0, elapsed - paused) / max(budget - paused, 1e-6)
            want_stage = 2 if progress_frac >= 1 - cfg.stage2_fraction and cfg.stage2_fraction > 0 else 1
            # Stop when the next step would end past the budget (a paper-preset step on a CPU takes
            # ~25 s). The first step of stage 2 is estimated from stage 1's by their rays per step;
            # when it would not fit, stage 1 goes on instead.
            if want_stage != state.stage:
                first = step_seconds * rays_per_step(cfg, want_stage) / rays_per_step(cfg, state.stage)
                if elapsed + first >= budget:
                    if not stage2_skipped:
                        say(f"stage 2 skipped: its first step (~{first:.0f} s) would end past the budget")
                        stage2_skipped = True
                    want_stage = state.stage
            if elapsed + step_seconds >= budget:
                break
        if want_stage != state.stage:
            state.stage = want_stage
            freeze_geometry(fields, capture, cfg.trains_geometry(2))
            opts = make_optimizers(fields, cfg, 2, capture)
            recent.clear()  # the logged PSNR speaks of one stage
            cfg = settle_stage2_sampler(fields, bank, probe, cfg, light_intensity(), capture, shard, say)
            what = f"the SDF at x{cfg.stage2_geometry_lr:g} its rate" if cfg.stage2_geometry_lr else "geometry frozen"
            say(f"stage 2 at step {state.step}: refining the BRDF, {what} ({rays_per_step(cfg, 2)} rays per step)")
            error_map = stage2_error_map(fields, bank, cfg, psf, light_intensity(), capture, shard, say)
            state.paused += warm_up_compiled(fields, bank, cfg, psf, 2, light_intensity(), capture, probe)
            elapsed = time.time() - t_start  # stage 2's set-up (check, map: 10-80 s) is not its first step's time
        set_learning_rate(opts, progress_frac, cfg, state.lr_scale)
        if cfg.coarse_to_fine > 0:  # without it every level stays open (the buffers' initial ones)
            fields.set_coarse_to_fine(progress_frac / cfg.coarse_to_fine if state.stage == 1 else 1.0)
        intensity = light_intensity()
        terms = compute_loss(fields, bank, cfg, psf, state.stage, gen, intensity, progress_frac, capture, shard,
                             anchors, error_map)
        if not shard.all_true(bool(torch.isfinite(terms.total))):
            state.rollbacks += 1
            if state.rollbacks > 5:
                raise SrvolError("training diverged: the loss stayed non-finite after 5 rollbacks")
            ck = load_checkpoint(ckpt_dir, fields, capture, cfg.trains_geometry(2))
            state.lr_scale *= 0.5
            if ck is not None:
                state.step, state.stage = ck.state.step, ck.state.stage
                opts = restore_optimizers(fields, cfg, ck, capture)
            say(f"non-finite loss at step {state.step}: rolled back to step {last_good_step} "
                f"with learning rate x{state.lr_scale:g}")
            continue
        take_step(opts, terms.total, shard)
        if state.stage == 1 and cfg.beta_anneal > 0:
            fields.cap_beta(beta_cap(progress_frac, cfg.beta_anneal, cfg.beta_cap_end))
        state.step += 1
        recent.append((terms.squared_error, terms.pixels))
        state.elapsed = time.time() - t_start
        step_seconds = state.elapsed - elapsed
        if state.step % cfg.log_every == 0 and main:
            rec = {"step": state.step, "stage": state.stage, "seconds": round(state.elapsed, 2),
                   "loss": round(float(terms.total.detach()), 6), "l1": round(terms.photometric, 6),
                   "eikonal": round(terms.eikonal, 6), "mask": round(terms.mask, 6),
                   **({"smooth": round(terms.smooth, 6)} if cfg.lambda_smooth > 0 else {}),
                   "psnr": round(recent_psnr(recent), 3),
                   "probe_psnr": round(probe_psnr(fields, bank, probe, cfg, state.stage, intensity, capture), 3),
                   "beta": round(float(fields.beta.detach()), 6)}
            with open(log_path, "a") as f:
                f.write(json.dumps(rec) + "\n")
            bar.set_postfix(loss=f"{float(terms.total.detach()):.4f}", psnr=f"{recent_psnr(recent):.2f}",
                            stage=state.stage)
        if cfg.iters:
            bar.update(1)
        else:
            bar.n = min(int(state.elapsed), int(budget))
            bar.refresh()
        if cfg.snapshots and snaps_done < cfg.snapshots and main:
            frac = state.step / cfg.iters if cfg.iters else state.elapsed / budget
            if frac >= (snaps_done + 1) / cfg.snapshots - 1e-9 or frac >= 1.0:
                snaps_done += 1
                save_snapshot(run_dir / "snapshots", fields, state.step, state.elapsed)
        if state.step % cfg.checkpoint_every == 0:
            reason = check_not_collapsed(fields, device)
            if reason:
                raise SrvolError(f"step {state.step}: {reason}")
            if main:
                save_checkpoint(ckpt_dir, fields, opts, state, gen.get_state(), capture)
            last_good_step = state.step
    bar.close()
    reason = check_not_collapsed(fields, device)
    if reason:
        raise SrvolError(reason)
    if not main:
        shard.barrier()  # rank 0 writes the model: when train() returns, the run is complete on every rank
        return TrainSummary(iterations=state.step, train_seconds=state.elapsed,
                            final_psnr=recent_psnr(recent), rollbacks=state.rollbacks,
                            stage2_samples=samples_in_words(cfg) if state.stage == 2 else "")
    save_checkpoint(ckpt_dir, fields, opts, state, gen.get_state(), capture)
    if cfg.snapshots and snaps_done < cfg.snapshots:
        save_snapshot(run_dir / "snapshots", fields, state.step, state.elapsed)
    write_model(run_dir, fields)
    if capture is not None:
        atomic_write_text(run_dir / CAPTURE_TERMS_NAME, json.dumps(capture.values(scene.train), indent=1) + "\n")
    shard.barrier()
    return TrainSummary(iterations=state.step, train_seconds=state.elapsed,
                        final_psnr=recent_psnr(recent), rollbacks=state.rollbacks,
                        stage2_samples=samples_in_words(cfg) if state.stage == 2 else "")
