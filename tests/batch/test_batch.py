"""`srvol batch` as a user runs it, on a local Ray: three tiny scenes, one of them broken; a run
again that finds everything done; a training process killed with `kill -9` that resumes."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from srvol.checkpoint import STATE_NAME as CHECKPOINT_STATE
from srvol.batch.steps import JobSpec, Source, error_line, pending_steps, step_command

TINY = ["--iters", "12", "--threads", "1", "--quiet"]


@pytest.fixture(scope="module")
def tiny_scenes(tmp_path_factory) -> Path:
    """Two tiny copies of the default scene (LR 24x18, 6 + 1 views) and one with a corrupt cameras.json."""
    from srvol.synth.generate import SynthOptions, synthesize

    root = tmp_path_factory.mktemp("batch_scenes")
    for name, seed in (("pot", 0), ("vase", 1)):
        synthesize("bumpy", root / name, SynthOptions(lr=(24, 18), views=6, test_views=1, relit_views=1, ss=1,
                                                      seed=seed), progress=False)
    broken = root / "broken"
    synthesize("bumpy", broken, SynthOptions(lr=(24, 18), views=6, test_views=1, relit_views=1, ss=1),
               progress=False)
    (broken / "cameras.json").write_text("{ not json")
    return root


def _batch(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "srvol", "batch", *args], capture_output=True, text=True,
                          env=env, timeout=timeout)


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.stat().st_size)
            for p in folder.rglob("*") if p.is_file()}


def test_a_batch_finishes_the_good_sources_and_names_the_broken_one(tiny_scenes, tmp_path):
    out = tmp_path / "batch"
    first = _batch(*(str(tiny_scenes / n) for n in ("pot", "broken", "vase")), "--out", str(out), *TINY)
    assert first.returncode == 1, first.stderr[-3000:]  # one source failed
    rows = {r["name"]: r for r in json.loads((out / "batch.json").read_text())}
    assert rows["pot"]["status"] == rows["vase"]["status"] == "complete"
    assert rows["broken"]["status"] == "failed"
    assert "cameras.json" in rows["broken"]["error"] and "\n" not in rows["broken"]["error"]
    table = (out / "batch.md").read_text()
    assert f"| broken | failed: {rows['broken']['error']}" in table
    for name in ("pot", "vase"):
        assert (out / name / "report.html").is_file() and (out / name / "asset").is_dir()
        assert rows[name]["metrics"]["psnr_hr"] > 10 and rows[name]["seconds"]["train"] > 0
    index = (out / "index.html").read_text()
    assert 'href="pot/report.html"' in index and 'href="vase/report.html"' in index

    # the complete sources again: skipped (no Ray, no step), nothing of theirs touched
    good = [str(tiny_scenes / "pot"), str(tiny_scenes / "vase"), "--out", str(out), *TINY]
    before = _snapshot(out / "pot")
    assert _batch(*good).returncode == 0
    assert _snapshot(out / "pot") == before
    # and the same command once more: everything is complete, so no file at all changes
    before = _snapshot(out)
    t0 = time.time()
    again = _batch(*good)
    assert again.returncode == 0, again.stderr[-3000:]
    assert time.time() - t0 <= 10.0
    assert _snapshot(out) == before


def test_a_killed_training_is_retried_and_resumes_from_its_checkpoint(tiny_scenes, tmp_path):
    out = tmp_path / "batch"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "srvol", "batch", str(tiny_scenes / "pot"), "--out", str(out),
                             "--iters", "60", "--threads", "1", "--quiet", "--steps", "train",
                             "--train-args=--checkpoint-every 10"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    running, ckpts = out / "pot" / "running.json", out / "pot" / "run" / "checkpoints"
    deadline = time.time() + 240
    killed = None
    while time.time() < deadline and killed is None and proc.poll() is None:
        try:
            job = json.loads(running.read_text())
        except (OSError, ValueError):
            job = None
        if job and job["step"] == "train" and (ckpts / CHECKPOINT_STATE).is_file():
            os.kill(job["pid"], signal.SIGKILL)
            killed = job["pid"]
        time.sleep(0.2)
    assert killed, "the training never reached its first checkpoint"
    stdout, stderr = proc.communicate(timeout=400)
    assert proc.returncode == 0, stderr[-3000:]
    log = (out / "pot" / "logs" / "train.log").read_text()
    resumed = [int(line.split()[3]) for line in log.splitlines() if line.startswith("resuming at step")]
    assert resumed and resumed[0] > 0, log[-2000:]
    assert json.loads((out / "pot" / "run" / "train_summary.json").read_text())["iterations"] == 60


def test_a_cut_off_training_resumes_and_finished_steps_are_not_pending(tmp_path):
    src = Source("pot", tmp_path / "scene", "scene", tmp_path / "out")
    spec = JobSpec(iters=10)
    assert pending_steps(src, spec) == ["train", "eval", "export", "report"]
    assert "--force" in step_command(src, "train", spec)
    (src.run / "checkpoints").mkdir(parents=True)
    (src.run / "config.json").write_text("{}")
    (src.run / "checkpoints" / CHECKPOINT_STATE).write_text("{}")
    assert "--resume" in step_command(src, "train", spec) and "--force" not in step_command(src, "train", spec)


def test_a_step_error_is_one_line():
    log = "$ srvol train x\npreset auto\nsrvol: error: /x/cameras.json: not valid JSON (line 1)\n"
    assert error_line(log) == "srvol: error: /x/cameras.json: not valid JSON (line 1)"
    assert error_line("") == "failed without output"
