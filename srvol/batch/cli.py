"""``srvol batch SOURCES... --out DIR``: many objects through the whole pipeline, as Ray tasks.

One Ray task per source runs its pending steps (:mod:`srvol.batch.steps`) with a resource request
of ``--threads`` CPUs (and one GPU where the cluster has them). A local Ray starts inside the
command unless ``--address`` names a cluster. A complete batch run again starts nothing.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from srvol.batch.steps import (RUNNING_NAME, STEPS, JobSpec, Source, StepDied, pending_steps, read_state,
                               run_source, source_kind, write_state)
from srvol.batch.summary import source_row, write_summary
from srvol.errors import SrvolError

RETRIES = 2
"""Times a job is run again after its worker or a step's process died (training resumes)."""


def add_parser(sub) -> None:
    p = sub.add_parser(
        "batch", help="run many sources through import, train, eval, export and report (Ray)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Every source (a scene folder, or a folder of photos for `srvol import`) goes through the "
                    "steps as a Ray task. A local Ray starts inside the command; --address runs on a cluster:\n\n"
                    "  head:    ray start --head --port 6379\n"
                    "  workers: ray start --address HEAD_IP:6379\n"
                    "  then:    srvol batch SOURCES... --out DIR --address auto   (on the head)\n\n"
                    "OUT/NAME/ gets run/, asset/, report.html, logs/ and steps.json; OUT gets batch.md, batch.json "
                    "and index.html. Run the same command again to finish what is not complete (training resumes "
                    "from its checkpoint); complete sources are skipped. A source with bad input fails alone.")
    p.add_argument("sources", nargs="+", type=Path, help="scene folders or folders of photos")
    p.add_argument("--out", type=Path, required=True, help="batch folder (one sub-folder per source)")
    p.add_argument("--steps", default=",".join(STEPS),
                   help=f"comma list, in pipeline order, of {', '.join(STEPS)} (default all; import applies to "
                        "photo folders only)")
    p.add_argument("--threads", type=int, default=2, help="CPUs per job: Ray's resource request and each step's "
                                                          "OMP_NUM_THREADS (default 2)")
    p.add_argument("--time-budget", type=float, default=600.0, help="training seconds per source (default 600)")
    p.add_argument("--iters", type=int, help="train this many iterations instead of --time-budget")
    p.add_argument("--format", default="usd,glb", help="export formats (default usd,glb)")
    p.add_argument("--train-args", default="", metavar="'FLAGS'",
                   help="extra `srvol train` flags for every source, e.g. --train-args='--preset fast'")
    p.add_argument("--address", help="Ray cluster to run on: auto, HOST:PORT or ray://HOST:PORT "
                                     "(default: a local Ray inside this command)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or status lines")
    p.set_defaults(func=run_batch)


def resolve_sources(paths: list[Path], out: Path) -> list[Source]:
    """One Source per path; names are the folder names (the parent's for a folder called photos or
    images: mug/photos is 'mug'), made unique with -2, -3, ..."""
    sources, seen = [], {}
    for path in paths:
        full = path.resolve()
        base = (full.parent.name if full.name.lower() in ("photos", "images") else full.name) or "source"
        seen[base] = seen.get(base, 0) + 1
        name = base if seen[base] == 1 else f"{base}-{seen[base]}"
        sources.append(Source(name=name, path=path.resolve(), kind=source_kind(path), out=out.resolve() / name))
    return sources


def job_spec(args) -> JobSpec:
    steps = tuple(s for s in args.steps.split(",") if s)
    unknown = [s for s in steps if s not in STEPS]
    if unknown or not steps:
        raise SrvolError(f"--steps {args.steps}: choose from {', '.join(STEPS)}")
    if list(steps) != sorted(steps, key=STEPS.index):
        raise SrvolError(f"--steps {args.steps}: give them in pipeline order ({' -> '.join(STEPS)})")
    if args.threads < 1:
        raise SrvolError("--threads must be at least 1")
    import shlex

    return JobSpec(steps=steps, threads=args.threads, time_budget=args.time_budget, iters=args.iters,
                   export_format=args.format, train_args=tuple(shlex.split(args.train_args)))


def run_batch(args) -> int:
    spec = job_spec(args)
    sources = resolve_sources(args.sources, args.out)
    todo = [s for s in sources if pending_steps(s, spec) or not s.kind]
    args.out.mkdir(parents=True, exist_ok=True)
    say = (lambda *_: None) if args.quiet else print
    if todo:
        say(f"{len(sources) - len(todo)} of {len(sources)} sources complete; running {len(todo)}")
        try:
            _run_on_ray(todo, spec, args.address, args.quiet)
        except KeyboardInterrupt:
            print("srvol: interrupted -- finished steps are kept; run the same command again to continue",
                  file=sys.stderr)
            return 130
    rows = [source_row(s, spec) for s in sources]
    write_summary(args.out, rows, spec)
    failed = [r for r in rows if r.status != "complete"]
    say(f"{len(rows) - len(failed)} of {len(rows)} sources complete -> {args.out / 'batch.md'}, "
        f"{args.out / 'index.html'}")
    for r in failed:
        print(f"  {r.name}: {r.error or r.status}", file=sys.stderr)
    return 1 if failed else 0


def _run_on_ray(todo: list[Source], spec: JobSpec, address: str | None, quiet: bool) -> None:
    import logging

    import ray
    from tqdm import tqdm

    # Ray starts its workers at nice 15, for work in the background of a busy machine; here the jobs
    # are the work (a local Ray; a cluster's own `ray start` sets its own)
    os.environ.setdefault("RAY_worker_niceness", "0")
    ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR,
             configure_logging=True)
    try:
        gpu = ray.cluster_resources().get("GPU", 0) >= 1
        if gpu:
            spec = JobSpec(**{**spec.__dict__, "device": "cuda"})
        task = ray.remote(run_source).options(num_cpus=spec.threads, num_gpus=1 if gpu else 0,
                                              max_retries=RETRIES, retry_exceptions=[StepDied])
        refs = {task.remote(src, spec): src for src in todo}
        total = sum(len(pending_steps(s, spec)) for s in todo)
        bar = tqdm(total=total, unit="step", desc="batch", disable=quiet)
        shown: dict[str, str] = {}
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1, timeout=1.0)
            for ref in ready:
                src = refs.pop(ref)
                try:
                    result = ray.get(ref)
                except (ray.exceptions.RayTaskError, ray.exceptions.WorkerCrashedError) as e:
                    result = {"status": "failed", "error": _one_line(e)}
                    _record_error(src, result["error"])
                bar.write(f"{src.name}: {result['status']}" + (f" ({result['error']})" if result["error"] else ""))
            for src in refs.values():  # a status line when a job moves to its next step
                step = _running_step(src)
                if step and shown.get(src.name) != step:
                    shown[src.name] = step
                    bar.write(f"{src.name}: {step}")
            done = total - sum(len(pending_steps(s, spec)) for s in todo)
            if done != bar.n:
                bar.update(done - bar.n)
        bar.close()
    finally:
        ray.shutdown()


def _running_step(src: Source) -> str | None:
    try:
        return json.loads((src.out / RUNNING_NAME).read_text())["step"]
    except (OSError, ValueError, KeyError):
        return None


def _one_line(e: Exception) -> str:
    """A Ray failure as one line: the cause's own message where there is one."""
    cause = getattr(e, "cause", None)
    text = str(cause) if cause is not None else str(e)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else type(e).__name__


def _record_error(src: Source, error: str) -> None:
    state = read_state(src)
    state["error"] = error
    src.out.mkdir(parents=True, exist_ok=True)
    write_state(src, state)

