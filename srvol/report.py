"""``srvol report RUN``: one self-contained HTML page (images inlined) of a run and its products.

It reads files only, and leads with what its reader came for:

1. the asset: previews under moved lights (``--previews DIR``), the files written and how to open
   them (Blender, ``srvol view``, ``relight``) (``--asset DIR``);
2. how good and how long, in words (from metrics.json and train_summary.json), and the held-out
   views against the ground truth (eval_sheet.png);
3. diagnostics below: the training configuration, the raw tables, other folders (``--include``),
   the committed benchmarks and the commands that reproduce each part.

It is the composition root's neighbour (it may read an asset folder's manifest).
"""
from __future__ import annotations

import base64
import html
import json
import shlex
from dataclasses import dataclass
from pathlib import Path

from srvol.atomic import atomic_write_text

BENCH_RESULTS = Path(__file__).resolve().parent.parent / "bench" / "results"

FILE_HELP = {
    "usd": "USD (UsdPreviewSurface). Blender: File > Import > Universal Scene Description; also usdview, Omniverse",
    "usdc": "USD, binary crate. Blender: File > Import > Universal Scene Description",
    "usdz": "USD zip package (textures inside). Blender: File > Import > Universal Scene Description; "
            "Apple Quick Look",
    "gltf": "glTF 2.0 (+ .bin and textures). Blender: File > Import > glTF 2.0; any glTF viewer",
    "glb": "glTF 2.0, one binary file. Blender: File > Import > glTF 2.0; any glTF viewer or web page",
    "obj": "OBJ + MTL (no specular workflow). Blender: File > Import > Wavefront (.obj)",
    "blend": "Blender scene, material set up. Blender: File > Open",
}
RAW_HELP = "raw/*.exr: the lossless linear maps (albedo, F0, alpha, roughness = sqrt(alpha)) that `relight` reads"


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


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text()) if path.is_file() else {}
    except json.JSONDecodeError:
        return {}


# ----------------------------------------------------------------------------- in words

@dataclass(frozen=True)
class Band:
    """Words for a value at or above ``floor`` (bands are tried from the best down)."""

    floor: float
    words: str


PSNR_WORDS = (Band(40.0, "excellent: side by side, differences are hard to find"),
              Band(35.0, "very good: differences show in the error image, rarely to the eye"),
              Band(30.0, "good: small differences are visible up close"),
              Band(25.0, "fair: visible differences (blur, wrong shading in places)"),
              Band(float("-inf"), "poor: the renders differ clearly from the ground truth"))
NORMAL_WORDS = (Band(-5.0, "very accurate"), Band(-10.0, "accurate"), Band(-20.0, "rough in places"),
                Band(float("-inf"), "inaccurate"))
"""Normal error bands on the negated angle (smaller errors are better): < 5, < 10, < 20 degrees."""


def in_words(value: float, bands: tuple[Band, ...]) -> str:
    return next(b.words for b in bands if value >= b.floor)


def duration(seconds: float) -> str:
    """``372.4`` -> ``6 min 12 s``; under a minute: ``42 s``."""
    s = int(round(seconds))
    return f"{s // 60} min {s % 60} s" if s >= 60 else f"{s} s"


def headline(metrics: dict, summary: dict) -> list[str]:
    """Sentences on quality and time from metrics.json and train_summary.json (what is missing is left out)."""
    out = []
    seconds = summary.get("train_seconds", metrics.get("train_seconds"))
    steps = summary.get("iterations", metrics.get("iterations"))
    if seconds is not None:
        out.append(f"Training took {duration(float(seconds))}" + (f" ({int(steps)} steps)." if steps else "."))
    if "psnr_hr" in metrics:
        p = float(metrics["psnr_hr"])
        ssim = f", SSIM {float(metrics['ssim_hr']):.3f}" if "ssim_hr" in metrics else ""
        out.append(f"On views held out from training, rendered at the super-resolved size, the model matches "
                   f"the ground truth at {p:.1f} dB PSNR{ssim}: {in_words(p, PSNR_WORDS)}.")
    if "relit_psnr" in metrics:
        p = float(metrics["relit_psnr"])
        out.append(f"Under lights moved away from the camera (with shadows) it scores {p:.1f} dB: "
                   f"{in_words(p, PSNR_WORDS)}.")
    if "normal_mae_deg" in metrics:
        d = float(metrics["normal_mae_deg"])
        out.append(f"The surface orientation is off by {d:.1f} degrees on average ({in_words(-d, NORMAL_WORDS)}).")
    if "chamfer" in metrics:
        out.append(f"The shape is within {100 * float(metrics['chamfer']):.2f}% of the object's size of the true "
                   "surface (Chamfer distance).")
    if float(metrics.get("dark_fraction", 0.0)) > 0.5:
        out.append("Warning: most renders are far darker than the ground truth: the run may have collapsed.")
    return out


# ----------------------------------------------------------------------------- sections

def asset_section(asset: Path, scene: Path | None) -> list[str]:
    """The files of an asset folder, how to open each, and the commands that show it live."""
    meta = _read_json(asset / "asset.json")
    files = meta.get("files", {})
    rows = "".join(f"<tr><td><code>{html.escape(str(asset / name))}</code></td>"
                   f"<td>{html.escape(FILE_HELP.get(fmt, fmt))}</td></tr>" for fmt, name in files.items())
    rows += f"<tr><td><code>{html.escape(str(asset / 'raw'))}/</code></td><td>{html.escape(RAW_HELP)}</td></tr>"
    view = ["srvol", "view", str(asset)] + (["--scene", str(scene)] if scene is not None else [])
    relight = ["relight", str(asset), "--light-pos", "1.5,-1.5,1.5", "--material", "roughness-scale=0.5",
               "--out", "relit.png"]
    return ["<h2>Files written, and how to open them</h2>", f"<table>{rows}</table>",
            "<p><b>Look at it live</b> in the browser (drag the light, edit the material, export the edit):</p>",
            f"<pre>{html.escape(shlex.join(view))}</pre>",
            "<p>Render it under any point light, with shadows and material edits:</p>",
            f"<pre>{html.escape(shlex.join(relight))}</pre>"]


def build_report(run: Path, extra_dirs: list[Path], commands: list[str], asset: Path | None = None,
                 previews: Path | None = None, scene: Path | None = None) -> str:
    from srvol.config import describe_psf_rays, read_run_config

    cfg = read_run_config(run)  # one clear line for a missing, malformed or foreign config.json
    metrics, summary = _read_json(run / "metrics.json"), _read_json(run / "train_summary.json")
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>srvol report</title>",
             "<style>body{font-family:sans-serif;margin:2em;background:#fafafa;color:#222;max-width:1200px}"
             "table{border-collapse:collapse}td{border:1px solid #ccc;padding:2px 8px}"
             "pre{background:#eee;padding:8px;overflow-x:auto}h2{margin-top:1.5em}"
             ".previews{display:flex;gap:8px;flex-wrap:wrap}.previews figure{margin:0;flex:1;min-width:240px}"
             ".previews img{width:100%}.diag{margin-top:3em;border-top:2px solid #999}</style></head><body>",
             f"<h1>srvol report: {html.escape(run.name)}</h1>"]
    pngs = sorted(previews.glob("*.png")) if previews is not None and previews.is_dir() else []
    if pngs:
        parts.append("<h2>Your asset under moved lights</h2><div class='previews'>")
        parts += [f"<figure>{_img(p)}<figcaption>{html.escape(p.stem)}</figcaption></figure>" for p in pngs]
        parts.append("</div>")
    if asset is not None and asset.is_dir():
        scene_dir = scene if scene is not None else cfg.scene.path
        parts += asset_section(asset, Path(scene_dir) if scene_dir else None)
    sentences = headline(metrics, summary)
    if sentences:
        parts.append("<h2>How good, how long</h2>" + "".join(f"<p>{html.escape(s)}</p>" for s in sentences))
    if (run / "eval_sheet.png").is_file():
        parts.append("<h2>Held-out views against the ground truth</h2>"
                     "<p>A row per held-out view: ground truth | this model | difference x4 (brighter = larger) | "
                     "normals, ours | normals, true | the low-resolution input. Then a row per moved light of the "
                     "ground truth: truth | this model | difference.</p>"
                     + _img(run / "eval_sheet.png"))

    parts.append("<div class='diag'><h2>Diagnostics</h2>")
    t = cfg.train
    rays = describe_psf_rays(t, cfg.scene.psf)
    parts.append(f"<h3>Training</h3><p>preset <b>{html.escape(t.preset)}</b>, PSF model "
                 f"<b>{html.escape(t.sr)}</b>, {html.escape(rays)}.</p>")
    if t.reasons:
        parts.append("<ul>" + "".join(f"<li>{html.escape(r)}</li>" for r in t.reasons) + "</ul>")
    for name, d in (("train_summary.json", summary), ("metrics.json", metrics)):
        if d:
            parts.append(f"<h3>{name}</h3>" + _table(d))
    for d in extra_dirs:
        more = sorted(d.glob("*.png")) if d.is_dir() else []
        if more:
            parts.append(f"<h3>{html.escape(d.name)}</h3>")
            parts += [f"<p>{html.escape(p.name)}</p>{_img(p, '48%')}" for p in more]
        rep = d / "export_report.json"
        if rep.is_file():
            parts.append("<h3>export report</h3>" + _table(json.loads(rep.read_text())))
    if asset is not None and (stats := _read_json(asset / "asset.json").get("stats")):
        parts.append("<h3>export (asset.json stats)</h3>" + _table(stats))
    if BENCH_RESULTS.is_dir():
        parts.append("<h3>Benchmarks (committed, bench/results)</h3>")
        for md in sorted(BENCH_RESULTS.glob("*.md")):
            parts.append(f"<h4>{html.escape(md.name)}</h4>" + _md_table(md))
        for png in sorted(BENCH_RESULTS.glob("*.png")):
            parts.append(f"<h4>{html.escape(png.name)}</h4>" + _img(png, "80%"))
    if commands:
        parts.append("<h3>Reproduce</h3><pre>" + html.escape("\n".join(commands)) + "</pre>")
    parts.append("</div></body></html>")
    return "\n".join(parts)


def add_parser(sub) -> None:
    p = sub.add_parser("report", help="write a self-contained HTML report of a run",
                       description="One HTML file: the asset under moved lights, its files and how to open them "
                                   "(Blender, srvol view), quality and time in words, the held-out views against "
                                   "the ground truth; then diagnostics (config, metrics, benchmarks, commands).")
    p.add_argument("run", type=Path)
    p.add_argument("--out", type=Path, help="HTML file (default RUN/report.html)")
    p.add_argument("--asset", type=Path, metavar="DIR",
                   help="the exported asset folder: its files, how to open them, the srvol view command")
    p.add_argument("--previews", type=Path, metavar="DIR", help="folder of relit PNGs shown first, side by side")
    p.add_argument("--scene", type=Path, metavar="DIR",
                   help="scene folder for the srvol view command's cameras (default: the run's scene)")
    p.add_argument("--include", type=Path, action="append", default=[],
                   help="extra folder of PNGs to show among the diagnostics (e.g. the scene); repeatable")
    p.add_argument("--commands", type=Path, help="text file of the commands that produced the run")
    p.set_defaults(func=_run_report)


def _run_report(args) -> int:
    commands = args.commands.read_text().splitlines() if args.commands and args.commands.is_file() else []
    out = args.out or args.run / "report.html"
    atomic_write_text(out, build_report(args.run, args.include, commands, asset=args.asset, previews=args.previews,
                                        scene=args.scene))
    print(f"wrote {out}")
    return 0
