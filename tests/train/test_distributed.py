"""Data-parallel training as worked examples: two gloo ranks that each render half of every step
train the same parameters as one process stepping on the whole step; torchrun runs and resumes."""
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import torch
import torch.multiprocessing as mp

from srvol.presets import auto_config
from srvol.data import load_scene
from srvol.distributed import SINGLE, Shard
from srvol.train import train

STEPS = 5


def _config(scene):
    """auto's structure with small batches: 5 steps, the last two in stage 2 (lattice patches)."""
    cfg = auto_config(scene, "gaussian", 60.0)
    return replace(cfg, iters=STEPS, time_budget=0.0, checkpoint_every=10_000, log_every=1,
                   batch_in=64, batch_out=32, batch_eikonal=64, batch_stage2=128)


def _rank(rank: int, world: int, scene_dir: str, run: str, rendezvous: str) -> None:
    torch.distributed.init_process_group("gloo", init_method=f"file://{rendezvous}", rank=rank, world_size=world)
    try:
        torch.set_num_threads(1)
        scene = load_scene(Path(scene_dir))
        train(scene, _config(scene), Path(run), progress=False, say=lambda *_: None, shard=Shard(rank, world))
    finally:
        torch.distributed.destroy_process_group()


def _weights(run: Path) -> dict[str, torch.Tensor]:
    return torch.load(run / "model.pt", weights_only=True)


def test_shares_cover_the_batch_once():
    shares = [Shard(r, 3).span(10) for r in range(3)]
    assert shares == [(0, 4), (4, 7), (7, 10)]
    assert SINGLE.span(10) == (0, 10)


def test_two_gloo_ranks_train_what_one_process_trains_on_their_union(default_scene, tmp_path):
    scene = load_scene(default_scene)
    torch.set_num_threads(1)
    train(scene, _config(scene), tmp_path / "one", progress=False, say=lambda *_: None)

    mp.spawn(_rank, args=(2, str(default_scene), str(tmp_path / "two"), str(tmp_path / "rendezvous")),
             nprocs=2, join=True)

    one, two = _weights(tmp_path / "one"), _weights(tmp_path / "two")
    assert one.keys() == two.keys()
    moved = 0.0
    for k in one:
        # 1e-4: the all-reduce sums the two halves in another order, and Adam divides each step by
        # sqrt(v) + eps, so a weight whose gradients are near eps carries the rounding up to ~3e-5
        # (auto's 32-wide heads, albedo_net.2); steps move the weights by > 1e-3 (below)
        assert torch.allclose(one[k], two[k], atol=1e-4, rtol=0), (k, (one[k] - two[k]).abs().max())
        moved = max(moved, float((one[k] - _config_init(scene)[k]).abs().max()))
    assert moved > 1e-3  # the parameters did move: the comparison is not of two untouched models
    # rank 0 alone wrote the log: one line per step, both stages
    log = [json.loads(line) for line in (tmp_path / "two" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == list(range(1, STEPS + 1))
    assert {r["stage"] for r in log} == {1, 2}


def _config_init(scene) -> dict[str, torch.Tensor]:
    """The parameters before the first step (same seed as train())."""
    from srvol.fields import SceneFields

    cfg = _config(scene)
    torch.manual_seed(cfg.seed)
    return SceneFields(cfg.fields, learn_intensity=scene.info.light_intensity is None).state_dict()


def test_torchrun_trains_and_resumes(default_scene, tmp_path):
    run = tmp_path / "run"
    base = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
            "-m", "srvol", "train", str(default_scene), "--out", str(run), "--distributed", "--quiet",
            "--checkpoint-every", "4"]
    first = subprocess.run([*base, "--iters", "8"], capture_output=True, text=True, env=_one_thread(),
                           timeout=300)
    assert first.returncode == 0, first.stderr[-2000:]
    assert first.stdout.count("preset auto") == 1  # rank 0 alone speaks
    again = subprocess.run([*base, "--iters", "8", "--resume"], capture_output=True, text=True, env=_one_thread(),
                           timeout=300)
    assert again.returncode == 0, again.stderr[-2000:]
    assert "resuming at step 8" in again.stdout
    assert json.loads((run / "train_summary.json").read_text())["ranks"] == 2


def _one_thread() -> dict:
    import os

    return {**os.environ, "OMP_NUM_THREADS": "1"}
