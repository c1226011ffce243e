"""``srvol report RUN``: one self-contained HTML page (images inlined) of a run and its products.

It collects what exists: the run's config and metrics, the eval sheet, relit renders,
the export report, the committed benchmark tables and charts, and the commands that
reproduce each part. It is the composition root's neighbour: it reads files only.
"""
from __future__ import annotations

import base64
import html
import json
from pathlib import Path

from srvol.atomic import atomic_write_text

BENCH_RESULTS = Path(__file__).resolve().parent.parent / "bench" / "results"


def _img(path: Path, width: str = "100%") -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" style="max-width:{width}" alt="{html.escape(path.name)}">'


def _table(d: dict) -> str:
    rows = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{v:.4f}</td></tr>" if isinstance(v, float)
                   else f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>"
                   for k, v in d.items() if not isinstance(v, (list, dict)))
    return f"<table>{rows}</table>"


def _md_table(path: Path) -> str:
    """A markdown file shown as preformatted text (tables stay readable without a renderer)."""
    return f"<pre>{html.escape(path.read_text())}</pre>"


def build_report(run: Path, extra_dirs: list[Path], commands: list[str]) -> str:
    from srvol.config import describe_psf_rays, read_run_config

    cfg = read_run_config(run)  # one clear line for a missing, malformed or foreign config.json
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>srvol report</title>",
             "<style>body{font-family:sans-serif;margin:2em;background:#fafafa;color:#222}"
             "table{border-collapse:collapse}td{border:1px solid #ccc;padding:2px 8px}"
             "pre{background:#eee;padding:8px;overflow-x:auto}h2{margin-top:1.5em}</style></head><body>",
             f"<h1>srvol report: {html.escape(run.name)}</h1>"]
    parts.append("<h2>Training</h2>")
    t = cfg.train
    rays = describe_psf_rays(t, cfg.scene.psf)
    parts.append(f"<p>preset <b>{html.escape(t.preset)}</b>, PSF model "
                 f"<b>{html.escape(t.sr)}</b>, {html.escape(rays)}.</p>")
    reasons = t.reasons
    if reasons:
        parts.append("<ul>" + "".join(f"<li>{html.escape(r)}</li>" for r in reasons) + "</ul>")
    for name in ("train_summary.json", "metrics.json"):
        p = run / name
        if p.is_file():
            parts.append(f"<h3>{name}</h3>" + _table(json.loads(p.read_text())))
    if (run / "eval_sheet.png").is_file():
        parts.append("<h2>Held-out views (GT | ours | error | normals)</h2>" + _img(run / "eval_sheet.png"))
    for d in extra_dirs:
        pngs = sorted(d.glob("*.png")) if d.is_dir() else []
        if pngs:
            parts.append(f"<h2>{html.escape(d.name)}</h2>")
            parts += [f"<p>{html.escape(p.name)}</p>{_img(p, '48%')}" for p in pngs]
        rep = d / "export_report.json"
        if rep.is_file():
            parts.append("<h3>export report</h3>" + _table(json.loads(rep.read_text())))
    if BENCH_RESULTS.is_dir():
        parts.append("<h2>Benchmarks (committed, bench/results)</h2>")
        for md in sorted(BENCH_RESULTS.glob("*.md")):
            parts.append(f"<h3>{html.escape(md.name)}</h3>" + _md_table(md))
        for png in sorted(BENCH_RESULTS.glob("*.png")):
            parts.append(f"<h3>{html.escape(png.name)}</h3>" + _img(png, "80%"))
    if commands:
        parts.append("<h2>Reproduce</h2><pre>" + html.escape("\n".join(commands)) + "</pre>")
    parts.append("</body></html>")
    return "\n".join(parts)


def add_parser(sub) -> None:
    p = sub.add_parser("report", help="write a self-contained HTML report of a run",
                       description="One HTML file with the run's config, metrics, eval sheet, relit renders, "
                                   "export report, the committed benchmark tables/charts and the commands.")
    p.add_argument("run", type=Path)
    p.add_argument("--out", type=Path, help="HTML file (default RUN/report.html)")
    p.add_argument("--include", type=Path, action="append", default=[],
                   help="extra folder of PNGs to show (e.g. relit renders, an export folder); repeatable")
    p.add_argument("--commands", type=Path, help="text file of the commands that produced the run")
    p.set_defaults(func=_run_report)


def _run_report(args) -> int:
    commands = args.commands.read_text().splitlines() if args.commands and args.commands.is_file() else []
    out = args.out or args.run / "report.html"
    atomic_write_text(out, build_report(args.run, args.include, commands))
    print(f"wrote {out}")
    return 0
