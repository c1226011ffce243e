"""Capacity on the scene suite: auto's derived model scaled by ``srvol train --capacity F``, scene by scene.

    python -m bench.bench_capacity [--scenes glossy,dark,shiny,bumpy] [--factors 0.5,0.7,1,2] [--budget 600]
    python -m bench.bench_capacity --collect   # re-tabulate the finished runs, train nothing

auto derives its grids, hash table and head widths from the scene (`srvol/presets.py`); F scales all three
(the hash table by F^3, so x0.5 is about a sixth of the parameters). "Model no more than a scene needs" is
read off this table: if halving the model loses little (< 0.5 dB on the mean) auto is larger than the
scenes need, and if doubling it gains much (> 0.2 dB) it is smaller. Default scenes: tuning scenes only,
since a default is chosen here.

Runs share --work with `bench_suite` (default bench/work/suite): x1 is the suite's own SR run of the
scene, reused when there; other factors go to `<scene>_auto_gaussian_<budget>s_x<F>`. Resumable like the
suite. Writes capacity_table.md, capacity_table.json and capacity_psnr.png into --results.
"""
from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
from pathlib import Path

import numpy as np

from bench.bench_suite import add_run_arguments, ensure_scene, fmt, run_folder, scene_key, train_and_eval
from bench.paths import write_result
from srvol.cli_parser import OneLineParser

DEFAULT_SCENES = ("glossy", "dark", "shiny", "bumpy")
DEFAULT_FACTORS = (0.5, 0.7, 1.0, 2.0)


def factor_folder(work: Path, key: str, factor: float, args) -> Path:
    """x1 is the suite's SR run of the scene; any other factor gets its own folder beside it."""
    base = run_folder(work, key, "gaussian", args)
    return base if factor == 1.0 else base.with_name(f"{base.name}_x{factor:g}")


def factor_run(scene_dir: Path, factor: float, args) -> dict:
    """x1 is trained and scored as the suite does (moved-light metrics included), the others without them."""
    if factor == 1.0:
        return train_and_eval(scene_dir, factor_folder(args.work, scene_dir.name, 1.0, args), "gaussian", args)
    return train_and_eval(scene_dir, factor_folder(args.work, scene_dir.name, factor, args), "gaussian", args,
                          ("--capacity", f"{factor:g}"), ("--no-relit",))


def _value(row: dict, factor: float, key: str) -> float:
    v = row["runs"].get(f"{factor:g}", {}).get(key)
    return float(v) if isinstance(v, (int, float)) else float("nan")


def factor_means(rows: list[dict], factors: list[float], key: str) -> dict[float, float]:
    """Each factor's mean of ``key`` minus x1's, over the scenes that have both (NaN when none)."""
    out = {}
    for f in factors:
        d = [_value(r, f, key) - _value(r, 1.0, key) for r in rows]
        d = [x for x in d if math.isfinite(x)]
        out[f] = float(np.mean(d)) if d else float("nan")
    return out


def table(rows: list[dict], factors: list[float], args, command: str) -> str:
    head = " | ".join(f"x{f:g}" for f in factors)
    lines = [f"# Capacity: auto's model scaled by --capacity F, {args.budget:g} s per run (2-core CPU)", "",
             f"Each run: OMP_NUM_THREADS={args.threads_per_run}, {args.runs_at_once} run(s) sharing the machine at a "
             "time. Cells: HR PSNR (dB) on the held-out views, normal MAE (deg), and in brackets the change "
             "in HR PSNR against x1. Means are over the scenes with that factor and x1. Reproduce: "
             f"`srvol bench capacity {command}` (resumable; each run's commands below).", "",
             f"| scene | {head} |", "|" + "---|" * (len(factors) + 1)]
    for r in rows:
        cells = []
        for f in factors:
            hr, nm = _value(r, f, "psnr_hr"), _value(r, f, "normal_mae_deg")
            d = hr - _value(r, 1.0, "psnr_hr")
            cells.append("not run" if not math.isfinite(hr) else
                         f"{hr:.2f}, {nm:.2f} deg" + ("" if f == 1.0 or not math.isfinite(d) else f" ({d:+.2f})"))
        lines.append(f"| {r['scene']} ({r['set']}) | " + " | ".join(cells) + " |")
    hr, nm = factor_means(rows, factors, "psnr_hr"), factor_means(rows, factors, "normal_mae_deg")
    lines.append("| **mean change against x1** | " + " | ".join(
        "-" if f == 1.0 else f"**{fmt(hr[f], '+.2f')} dB**, {fmt(nm[f], '+.2f')} deg" for f in factors) + " |")
    lines += ["", "Per run:", "", "| scene | factor | parameters | iterations | train s | stage-2 swing dB (step) |",
              "|---|---|---|---|---|---|"]
    for r in rows:
        for f in factors:
            v = r["runs"].get(f"{f:g}", {})
            if "psnr_hr" in v:
                lines.append(f"| {r['scene']} | x{f:g} | {v['parameters'] / 1e6:.2f} M | {v['iterations']} | "
                             f"{v['train_seconds']:.0f} | {fmt(v.get('stage2_step_swing_db', float('nan')))} |")
    lines += ["", "Commands:", ""]
    lines += [f"- {r['scene']} x{k}: `{v['command']}`" for r in rows for k, v in r["runs"].items()]
    return "\n".join(lines) + "\n"


def chart(rows: list[dict], factors: list[float], out: Path) -> None:
    """capacity_psnr.png: HR PSNR change against x1 per scene, one bar per factor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    others = [f for f in factors if f != 1.0]
    means = factor_means(rows, factors, "psnr_hr")
    fig, ax = plt.subplots(figsize=(2 + 1.2 * (len(rows) + 1), 3.6))
    bar = 0.8 / max(1, len(others))
    for k, f in enumerate(others):
        vals = [_value(r, f, "psnr_hr") - _value(r, 1.0, "psnr_hr") for r in rows] + [means[f]]
        ax.bar(np.arange(len(rows) + 1) + (k - (len(others) - 1) / 2) * bar, np.nan_to_num(vals), bar,
               label=f"x{f:g}", color=f"C{k}")
    ax.axhline(0, color="k", lw=0.8)
    for y in (-0.5, 0.2):
        ax.axhline(y, color="0.5", lw=0.8, ls="--")
    ax.set_xticks(range(len(rows) + 1), [r["scene"] for r in rows] + ["mean"])
    ax.set_ylabel("HR PSNR against auto (x1), dB")
    ax.set_title("capacity: auto's model scaled (dashed: the -0.5 / +0.2 dB marks)")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "capacity_psnr.png", dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default=",".join(DEFAULT_SCENES), help="comma list of scenes (default: %(default)s)")
    ap.add_argument("--factors", default=",".join(f"{f:g}" for f in DEFAULT_FACTORS),
                    help="comma list of --capacity factors; 1 is auto as derived (default: %(default)s)")
    add_run_arguments(ap)
    args = ap.parse_args(argv)
    from srvol.synth.scenes import SCENES, scene_set

    scenes = [s for s in args.scenes.split(",") if s]
    try:
        factors = sorted({float(f) for f in args.factors.split(",") if f} | {1.0})
    except ValueError:
        ap.error(f"--factors: numbers like 0.5,1,2, not {args.factors!r}")
    unknown = [s for s in scenes if s not in SCENES]
    if unknown or any(f <= 0 for f in factors):
        ap.error(f"unknown scene {', '.join(unknown)} (scenes: {', '.join(SCENES)})" if unknown
                 else "--factors must be positive")
    rows = []
    for name in scenes:
        scene_dir = (args.work / "scenes" / scene_key(name, args.synth) if args.collect
                     else ensure_scene(name, args.work, args.synth))
        runs = {f"{f:g}": factor_run(scene_dir, f, args) for f in factors}
        rows.append({"scene": name, "set": scene_set(name), "runs": runs})
        print(f"{name}: " + ", ".join(f"x{k} {v.get('psnr_hr', '-')}" for k, v in runs.items()), flush=True)
    args.results.mkdir(parents=True, exist_ok=True)
    text = table(rows, factors, args, shlex.join(sys.argv[1:] if argv is None else argv))
    write_result(args.results / "capacity_table.md", text)
    write_result(args.results / "capacity_table.json", json.dumps(rows, indent=1, default=str))
    chart(rows, factors, args.results)
    print(text, flush=True)
    print(f"wrote {args.results / 'capacity_table.md'}, capacity_table.json and capacity_psnr.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
