"""The batch's summary: ``batch.md`` and ``batch.json`` (one row per source: status, metrics,
seconds per step) and ``index.html`` linking every report. Nothing in them depends on when they
were written, and a file whose text has not changed is not rewritten: a batch run again over
complete sources changes no file."""
from __future__ import annotations

import html
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

from srvol.atomic import atomic_write_text
from srvol.batch.steps import JobSpec, Source, pending_steps, read_state

METRICS = {"psnr_hr": "HR PSNR", "psnr_hr_masked": "masked PSNR", "normal_mae_deg": "normal MAE (deg)",
           "relit_psnr": "relit PSNR"}
"""The eval metrics the summary shows (DESIGN.md metric keys) and their column names."""


@dataclass(frozen=True)
class SourceRow:
    name: str
    source: str
    status: str  # complete | failed | incomplete
    error: str | None
    seconds: dict[str, float] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    iterations: int | None = None


def source_row(src: Source, spec: JobSpec) -> SourceRow:
    """What the source's folder says now."""
    state = read_state(src)
    metrics, iterations = {}, None
    try:
        m = json.loads((src.run / "metrics.json").read_text())
        metrics = {k: float(m[k]) for k in METRICS if isinstance(m.get(k), (int, float))}
    except (OSError, ValueError):
        pass
    try:
        iterations = int(json.loads((src.run / "train_summary.json").read_text())["iterations"])
    except (OSError, ValueError, KeyError):
        pass
    error = state.get("error")
    status = "failed" if error else "incomplete" if pending_steps(src, spec) or not src.kind else "complete"
    return SourceRow(name=src.name, source=str(src.path), status=status, error=error,
                     seconds={s: float(v) for s, v in state.get("seconds", {}).items()}, metrics=metrics,
                     iterations=iterations)


def _f(v: float | None, spec: str = ".2f") -> str:
    return "-" if v is None or not math.isfinite(v) else format(v, spec)


def batch_markdown(rows: list[SourceRow], spec: JobSpec) -> str:
    steps = [s for s in spec.steps if s != "import" or any("import" in r.seconds for r in rows)]
    done = sum(r.status == "complete" for r in rows)
    lines = [f"# srvol batch: {done} of {len(rows)} sources complete", "",
             f"Steps: {' -> '.join(steps)}; training "
             + (f"{spec.iters} iterations" if spec.iters else f"{spec.time_budget:g} s") + f" per source, "
             f"{spec.threads} thread{'s' if spec.threads > 1 else ''} per job. Each source's folder holds run/, asset/, report.html and logs/.", "",
             "| source | status | " + " | ".join(METRICS.values()) + " | iterations | "
             + " | ".join(f"{s} s" for s in steps) + " |",
             "|" + "---|" * (3 + len(METRICS) + len(steps))]
    for r in rows:
        status = r.status if not r.error else f"failed: {r.error}"
        lines.append(f"| {r.name} | {status.replace('|', '/')} | "
                     + " | ".join(_f(r.metrics.get(k)) for k in METRICS) + f" | {r.iterations or '-'} | "
                     + " | ".join(_f(r.seconds.get(s), ".0f") for s in steps) + " |")
    return "\n".join(lines) + "\n"


def index_html(rows: list[SourceRow]) -> str:
    items = []
    for r in rows:
        name = html.escape(r.name)
        if r.status == "complete":
            psnr = r.metrics.get("psnr_hr")
            extra = f" -- HR PSNR {psnr:.2f} dB" if psnr is not None else ""
            items.append(f'<li><a href="{name}/report.html">{name}</a>{extra}</li>')
        else:
            items.append(f"<li>{name}: {html.escape(r.error or r.status)}</li>")
    return ("<!doctype html>\n<html><head><meta charset='utf-8'><title>srvol batch</title></head><body>\n"
            f"<h1>srvol batch: {sum(r.status == 'complete' for r in rows)} of {len(rows)} complete</h1>\n"
            "<p>Table: <a href='batch.md'>batch.md</a> (<a href='batch.json'>batch.json</a>)</p>\n<ul>\n"
            + "\n".join(items) + "\n</ul>\n</body></html>\n")


def write_if_changed(path: Path, text: str) -> bool:
    """Atomically write ``text`` unless the file already holds it; whether it wrote."""
    try:
        if path.read_text() == text:
            return False
    except OSError:
        pass
    atomic_write_text(path, text)
    return True


def write_summary(out: Path, rows: list[SourceRow], spec: JobSpec) -> None:
    write_if_changed(out / "batch.md", batch_markdown(rows, spec))
    write_if_changed(out / "batch.json", json.dumps([asdict(r) for r in rows], indent=1) + "\n")
    write_if_changed(out / "index.html", index_html(rows))

