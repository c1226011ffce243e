"""One source's way through ``import -> train -> eval -> export -> report``.

Each step is one ``python -m srvol`` process whose output is written atomically, so a step is
complete exactly when its output exists (:func:`step_done`) and a batch run again redoes only what
is missing. A training that was cut off continues from its last checkpoint (``--resume``). What
each step took is kept in ``OUT/NAME/steps.json``; its output in ``OUT/NAME/logs/STEP.log``.

:func:`run_source` is the body of one Ray task (:mod:`srvol.batch.cli`): a step's process killed by
a signal (a lost worker, the OOM killer, ``kill -9``) raises :class:`StepDied`, which Ray retries;
a step that fails on bad input ends the source with its one-line error, and the batch goes on.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from srvol.atomic import atomic_write_text

STEPS = ("import", "train", "eval", "export", "report")
STATE_NAME = "steps.json"
RUNNING_NAME = "running.json"
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


@dataclass(frozen=True)
class Source:
    """One object of the batch: ``path`` as given, its ``kind`` ('scene': a scene folder, 'photos':
    a folder of photos for ``srvol import``, '': neither) and its output folder ``out``."""

    name: str
    path: Path
    kind: str
    out: Path

    @property
    def scene(self) -> Path:
        return self.path if self.kind == "scene" else self.out / "scene"

    @property
    def run(self) -> Path:
        return self.out / "run"

    @property
    def asset(self) -> Path:
        return self.out / "asset"

    @property
    def report(self) -> Path:
        return self.out / "report.html"

    @property
    def logs(self) -> Path:
        return self.out / "logs"


@dataclass(frozen=True)
class JobSpec:
    """What every source goes through: the steps, the threads (CPUs) of each job, the device and
    the training length (``iters`` instead of ``time_budget`` when given), the export formats and
    extra ``srvol train`` flags."""

    steps: tuple[str, ...] = STEPS
    threads: int = 2
    device: str = "cpu"
    time_budget: float = 600.0
    iters: int | None = None
    export_format: str = "usd,glb"
    train_args: tuple[str, ...] = ()


class StepDied(Exception):
    """A step's process was killed by a signal: the job is retried (training resumes)."""


class StepFailed(Exception):
    """A step ended with an error (bad input): the source fails with this one line."""


def source_kind(path: Path) -> str:
    if (path / "cameras.json").is_file():
        return "scene"
    if path.is_dir() and any(p.suffix.lower() in PHOTO_SUFFIXES for p in path.iterdir()):
        return "photos"
    return ""


def applies(src: Source, step: str) -> bool:
    """import only for photo folders; eval only for scenes with held-out test views (a capture's
    photos have no ground truth to score); every other step for every source."""
    if step == "import":
        return src.kind == "photos"
    if step == "eval":
        return has_test_views(src.scene)
    return True


def has_test_views(scene: Path) -> bool:
    """Whether the scene names held-out test views (True until it exists: its eval will say)."""
    if not (scene / "cameras.json").is_file():
        return True
    from srvol.data import load_scene
    from srvol.errors import SrvolError

    try:
        return bool(load_scene(scene, load_images=False).test)
    except SrvolError:
        return True


def step_done(src: Source, step: str) -> bool:
    """Whether the step's output exists (each is written atomically: whole or absent)."""
    return {
        "import": lambda: (src.scene / "cameras.json").is_file(),
        "train": lambda: (src.run / "model.pt").is_file() and (src.run / "train_summary.json").is_file(),
        "eval": lambda: (src.run / "metrics.json").is_file(),
        "export": lambda: src.asset.is_dir(),
        "report": lambda: src.report.is_file(),
    }[step]()


def pending_steps(src: Source, spec: JobSpec) -> list[str]:
    return [s for s in spec.steps if applies(src, s) and not step_done(src, s)]


def has_checkpoint(run: Path) -> bool:
    """A run that `srvol train --resume` can continue (its config and a whole checkpoint)."""
    from srvol.checkpoint import STATE_NAME as CHECKPOINT_STATE

    return (run / "config.json").is_file() and (run / "checkpoints" / CHECKPOINT_STATE).is_file()


def step_command(src: Source, step: str, spec: JobSpec) -> list[str]:
    """The ``srvol`` arguments of a step (a cut-off training resumes)."""
    if step == "import":
        return ["import", str(src.path), "--out", str(src.scene), "--force"]
    if step == "train":
        if has_checkpoint(src.run):
            return ["train", str(src.scene), "--out", str(src.run), "--resume", "--quiet"]
        length = ["--iters", str(spec.iters)] if spec.iters else ["--time-budget", f"{spec.time_budget:g}"]
        return ["train", str(src.scene), "--out", str(src.run), "--force", "--quiet", "--device", spec.device,
                *length, *spec.train_args]
    if step == "eval":
        return ["eval", str(src.run)]
    if step == "export":
        return ["export", str(src.run), "--format", spec.export_format, "--out", str(src.asset), "--force"]
    if step == "report":
        return ["report", str(src.run), "--out", str(src.report), "--asset", str(src.asset)]
    raise ValueError(step)


def read_state(src: Source) -> dict:
    path = src.out / STATE_NAME
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {"source": str(src.path), "seconds": {}, "error": None}


def write_state(src: Source, state: dict) -> None:
    atomic_write_text(src.out / STATE_NAME, json.dumps(state, indent=1) + "\n")


def _die_with_parent() -> None:
    """In the step's process: die when the worker that started it dies (Linux), and ignore Ctrl-C
    (the batch's driver stops the jobs itself)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def error_line(log_text: str) -> str:
    """The step's one-line error: its last 'error:' line, else its last line."""
    lines = [ln.strip() for ln in log_text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if "error:" in ln]
    return (errors or lines or ["failed without output"])[-1]


def run_step(src: Source, step: str, spec: JobSpec) -> float:
    """Run one step as its own process; its seconds. StepDied / StepFailed as above."""
    src.logs.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "srvol", *step_command(src, step, spec)]
    log = src.logs / f"{step}.log"
    start = log.stat().st_size if log.is_file() else 0
    env = dict(os.environ, OMP_NUM_THREADS=str(spec.threads))
    t0 = time.time()
    with open(log, "a") as f:
        f.write(f"$ srvol {' '.join(cmd[3:])}\n")
        f.flush()
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=env, preexec_fn=_die_with_parent)
        atomic_write_text(src.out / RUNNING_NAME, json.dumps({"step": step, "pid": proc.pid}) + "\n")
        rc = proc.wait()
    (src.out / RUNNING_NAME).unlink(missing_ok=True)
    if rc < 0:
        raise StepDied(f"{step}: its process was killed (signal {-rc})")
    if rc != 0:
        with open(log) as f:
            f.seek(start)
            raise StepFailed(f"{step}: {error_line(f.read())}")
    return time.time() - t0


def run_source(src: Source, spec: JobSpec) -> dict:
    """Every pending step of one source, in order (the body of a Ray task): {'status', 'error'}."""
    src.out.mkdir(parents=True, exist_ok=True)
    state = read_state(src)
    if not src.kind:
        state["error"] = f"{src.path}: not a scene folder (cameras.json) or a folder of photos"
        write_state(src, state)
        return {"status": "failed", "error": state["error"]}
    for step in spec.steps:
        if not applies(src, step) or step_done(src, step):  # asked step by step: an import decides eval
            continue
        try:
            seconds = run_step(src, step, spec)
        except StepFailed as e:
            state["error"] = str(e)
            write_state(src, state)
            return {"status": "failed", "error": str(e)}
        state["seconds"][step] = round(state["seconds"].get(step, 0.0) + seconds, 2)
        state["error"] = None
        write_state(src, state)
    return {"status": "complete", "error": None}
