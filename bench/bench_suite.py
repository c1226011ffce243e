"""Scene suite: auto's SR against noSR, Vol-SR and bicubic upsampling on every built-in scene,
tuning and report sets side by side (`srvol synth --list` names the sets).

    python -m bench.bench_suite [--budget 600] [--scenes torus,cup] [--variants none,gaussian,box]
    python -m bench.bench_suite --collect   # re-tabulate the finished runs, train nothing

Hours, not minutes: each scene is synthesised once (1-10 min at its default size), then every
variant trains for --budget seconds (~10 min at 600 s) and is scored by `srvol eval` (a few
minutes at 320x240). Run it over several sessions: synthesised scenes and finished runs are kept
under --work (default bench/work/suite, not committed) and skipped on the next call, so a killed
or partial suite continues where it stopped; only an unfinished run is trained again.

For each scene one row: the bicubic reference (each test view's own LR image upsampled, scored
against its HR GT: a 2D reference that sees the test view), HR PSNR and masked PSNR of every
variant, and per run normal MAE, albedo PSNR, relit PSNR, train PSNR at the end, iterations,
parameters and peak memory; means per set. Writes suite_table.md, suite_table.json and
suite_psnr.png into --results (default bench/results).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shlex
import sys
from pathlib import Path

import numpy as np

from bench.bench_train import RESULTS, WORK, _run, train_psnr_at_end
from bench.paths import write_result
from srvol.cli_parser import OneLineParser

VARIANTS = {"none": "noSR", "gaussian": "SR (auto)", "box": "Vol-SR"}
"""`srvol train --sr` values and their names in the table."""

RUN_KEYS = ("psnr_hr", "psnr_hr_masked", "ssim_hr", "normal_mae_deg", "albedo_psnr", "relit_psnr", "chamfer")


def suite_scenes() -> list[str]:
    from srvol.synth.scenes import REPORT_SCENES, TUNING_SCENES

    return [*TUNING_SCENES, *REPORT_SCENES]


def scene_key(name: str, synth_args: str) -> str:
    """The cache folder name of a scene: its name, plus a digest of any extra `srvol synth` flags."""
    return name if not synth_args else f"{name}-{hashlib.sha1(synth_args.encode()).hexdigest()[:8]}"


def ensure_scene(name: str, work: Path, synth_args: str) -> Path:
    """The scene folder, synthesised with the scene's own defaults (plus ``synth_args``) unless cached."""
    scene = work / "scenes" / scene_key(name, synth_args)
    if not (scene / "cameras.json").is_file():  # srvol synth writes atomically: a folder is whole or absent
        _run([sys.executable, "-m", "srvol", "synth", name, "--out", str(scene), "--force", *synth_args.split()])
    return scene


def length_args(args) -> list[str]:
    """How long each run trains: --iters N when given, else --time-budget."""
    return ["--iters", str(args.iters)] if args.iters else ["--time-budget", f"{args.budget:g}"]


def run_folder(work: Path, key: str, sr: str, args) -> Path:
    length = f"{args.iters}it" if args.iters else f"{int(args.budget)}s"
    return work / "runs" / f"{key}_auto_{sr}_{length}"


WARM_UP_ITERS = 40
"""Steps of the untimed run before each timed one: both stages' queries compile (stage 2 begins at 70 %)."""


def train_command(scene: Path, out: Path, sr: str, length: list[str], extra: tuple[str, ...]) -> list[str]:
    """`srvol train` of one variant into ``out``: ``length`` (--iters N or --time-budget S) and ``extra`` flags."""
    return ["srvol", "train", str(scene), "--out", str(out), "--sr", sr, *length, *extra, "--quiet", "--force"]


def warm_compile_cache(scene: Path, run: Path, sr: str, extra: tuple[str, ...]) -> None:
    """Compile the run's field queries into torch's on-disk cache with a short untimed run of the same
    flags, so the timed run starts warm. Cold, compiling took 110-130 s of a 600 s budget with two
    runs compiling at once (35 s warm; B-spline scenes most): 25-30 % fewer steps, by the order the
    runs happened in, not by their method (suite_tuning.md)."""
    warm = run.parent.parent / "warm-up" / run.name
    _run([sys.executable, "-m", *train_command(scene, warm, sr, ["--iters", str(WARM_UP_ITERS), "--compile", "on"],
                                               extra)])


def train_and_eval(scene: Path, run: Path, sr: str, args, extra: tuple[str, ...] = (),
                   eval_extra: tuple[str, ...] = ()) -> dict:
    """One variant's row: train and evaluate unless done before (--collect: never train). Keys of
    RUN_KEYS plus train PSNR, iterations, parameters, peak memory and the commands; 'error' or
    'missing' when there is no result. ``extra``: more `srvol train` flags (e.g. --capacity),
    ``eval_extra``: more `srvol eval` flags."""
    train = train_command(scene, run, sr, length_args(args), extra)
    ev = ["srvol", "eval", str(run), *eval_extra]
    row: dict = {"command": " ".join(train) + " && " + " ".join(ev)}
    summary, metrics = run / "train_summary.json", run / "metrics.json"
    try:
        if not summary.is_file() and not args.collect:
            if not args.iters and args.warm_up:
                warm_compile_cache(scene, run, sr, extra)
            _run([sys.executable, "-m", *train])
        if summary.is_file() and not metrics.is_file() and not args.collect:
            _run([sys.executable, "-m", *ev])
    except RuntimeError as e:  # a variant that fails is a result too
        return {**row, "error": str(e)}
    if not metrics.is_file():
        return {**row, "missing": True}
    m = json.loads(metrics.read_text())
    s = json.loads(summary.read_text())
    row.update({k: m[k] for k in RUN_KEYS if k in m})
    row.update(train_psnr=train_psnr_at_end(run), stage2_swing_db=stage2_swing_db(run),
               stage2_step_swing_db=stage2_swing_db(run, "psnr"),
               iterations=s["iterations"], train_seconds=s["train_seconds"], rules=run_rules(run),
               parameters=s.get("parameters", 0), peak_rss_gib=s.get("peak_rss_gib"))
    return row


def run_rules(run: Path) -> str:
    """The beta cap, refining samples, stage-1 rays, head width, material table and SDF interpolation
    a run trained with (config.json), and stage 2's samples per ray (train_summary.json), in words: runs of an older auto (beta free, no refining samples,
    64-wide heads, PSF pairs in stage 1 with a 2^14 material table, smoothstep SDF where the rule now
    picks the B-spline) and today's are told apart in the table."""
    from srvol.config import read_run_config

    cfg = read_run_config(run).train
    cap = f"beta cap {cfg.beta_cap_end:.4f}" if cfg.beta_anneal else "beta free"
    rays = ""
    if cfg.sr == "gaussian":
        rays = ", stage 1 centre rays" if cfg.psf_sampler == "centre" else f", {cfg.psf_samples} PSF rays"
    heads = f", heads {cfg.fields.sdf_hidden}" if cfg.fields.kind == "grid" else ""
    table = f", material 2^{cfg.fields.mat_table_log2}" if cfg.fields.kind == "grid" else ""
    c2f = f", coarse-to-fine {cfg.coarse_to_fine:g}" if cfg.coarse_to_fine else ""
    sdf = ", B-spline SDF" if cfg.fields.kind == "grid" and cfg.fields.sdf_interpolation == "bspline" else ""
    summary = run / "train_summary.json"
    s2 = json.loads(summary.read_text()).get("stage2_samples", "") if summary.is_file() else ""
    s2 = f", stage 2 {s2.replace(' ', '')} samples" if s2 else ""  # runs before the check recorded none
    drawn = f", stage 2 error map {cfg.stage2_importance:g}" if cfg.stage2_importance else ""
    moving = f", stage 2 SDF x{cfg.stage2_geometry_lr:g}" if cfg.stage2_geometry_lr else ""
    clip = f", L1 saturated at {cfg.photometric_clip:g}" if cfg.photometric_clip else ""
    stereo = (f", stereo pull {cfg.lambda_anchor:g}" if cfg.lambda_anchor else "") + (
        f", stereo free space {cfg.lambda_free_space:g}" if cfg.lambda_free_space else "")
    return (cap + (f", {cfg.sampler.n_refine} refining" if cfg.sampler.n_refine else "") + rays + heads + table + c2f
            + sdf + s2 + drawn + moving + clip + stereo)


def carried_over(rows: list[dict], name: str, sr: str) -> dict | None:
    """A variant's row from the table before (``rows``: :func:`previous_rows`), for a run whose folder
    is not on this machine (runs stay in the ignored work folder); its rules say so. A row that had no
    result (not run, or failed) is carried as it was, so the table still lists that run."""
    old = next((r["variants"].get(sr) for r in rows if r["scene"] == name), None)
    if not old or "psnr_hr" not in old:
        return old
    rules = old.get("rules", "-")
    return {**old, "rules": rules if rules.endswith("(earlier run)") else f"{rules} (earlier run)"}


def stage2_swing_db(run: Path, key: str = "probe_psnr") -> float:
    """The largest distance (dB) of stage 2's logged train PSNR from its running median, after the
    first 10 % of stage 2's log lines (NaN without a stage 2): how steady the BRDF refinement is.
    ``probe_psnr``: on fixed pixels and rays (the model's changes); ``psnr``: on each step's own
    pixels (also the draw's); a log without probe_psnr (older runs) gives NaN for it."""
    log_path = run / "log.jsonl"
    lines = log_path.read_text().splitlines() if log_path.is_file() else []
    psnr = [r[key] for r in map(json.loads, lines) if r.get("stage") == 2 and key in r]
    start = len(psnr) // 10
    devs = [abs(psnr[i] - float(np.median(psnr[: i + 1]))) for i in range(start, len(psnr))]
    return max(devs) if devs else float("nan")


def previous_rows(args) -> list[dict]:
    """The committed table's rows (``--results``/suite_table.json); none for a --synth variant."""
    path = args.results / "suite_table.json"
    return [] if args.synth or not path.is_file() else json.loads(path.read_text())


def scene_row(name: str, args, work: Path) -> dict:
    """Everything measured on one scene: its capture, the bicubic reference and each variant."""
    from srvol.data import load_scene
    from srvol.evaluate import bicubic_reference
    from srvol.synth.scenes import get_scene, scene_set

    key = scene_key(name, args.synth)
    scene_dir = work / "scenes" / key if args.collect else ensure_scene(name, work, args.synth)
    row = {"scene": name, "set": scene_set(name), "description": get_scene(name).description, "variants": {}}
    before = previous_rows(args) if args.collect else []
    if not (scene_dir / "cameras.json").is_file():
        old = next((r for r in before if r["scene"] == name), None)
        carried = {sr: carried_over(before, name, sr) for sr in args.variants}
        return {**old, "variants": {sr: v for sr, v in carried.items() if v}} if old else row
    scene = load_scene(scene_dir)
    v0 = scene.views[scene.test[0]].camera
    row.update(lr=f"{v0.width}x{v0.height}", psf_sigma=scene.info.psf_sigma_lr_px,
               views=f"{len(scene.train)}+{len(scene.test)}", bicubic=bicubic_reference(scene))
    for sr in args.variants:
        row["variants"][sr] = train_and_eval(scene_dir, run_folder(work, key, sr, args), sr, args)
        if args.collect and row["variants"][sr].get("missing"):
            row["variants"][sr] = carried_over(before, name, sr) or row["variants"][sr]
        print(f"{name} {sr}: " + json.dumps({k: v for k, v in row["variants"][sr].items() if k != "command"}),
              flush=True)
    return row


# ----------------------------------------------------------------------------- tables

def psnr_of(row: dict, column: str, key: str = "psnr_hr") -> float:
    """A scene's value in a column ('bicubic' or a variant); NaN when it has none."""
    src = row.get("bicubic", {}) if column == "bicubic" else row["variants"].get(column, {})
    v = src.get(key)
    return float(v) if isinstance(v, (int, float)) else float("nan")


SUBSET_VARIANTS = ("box",)
"""Variants run on a subset of the scenes (Vol-SR): they do not narrow the set means of the others."""


def set_means(rows: list[dict], columns: list[str], key: str) -> dict[str, dict[str, float]]:
    """Per set and column: the mean over the set's scenes that have every full-suite column (comparable
    means); a subset column (Vol-SR) is averaged over those of them it was run on, counted in
    ``scenes_<column>``."""
    out = {}
    main = [c for c in columns if c not in SUBSET_VARIANTS]
    for name in ("tuning", "report"):
        full = [r for r in rows if r["set"] == name and all(math.isfinite(psnr_of(r, c, key)) for c in main)]
        out[name] = {"scenes": len(full)}
        for c in columns:
            have = [psnr_of(r, c, key) for r in full if math.isfinite(psnr_of(r, c, key))]
            out[name][c] = float(np.mean(have)) if have else float("nan")
            if c in SUBSET_VARIANTS:
                out[name][f"scenes_{c}"] = len(have)
    return out


MIXED = " (mixed)"  # an SR - noSR whose two runs were not collected together (:func:`mixed_pair`)


def fmt(v, spec: str = ".2f") -> str:
    """A table cell: ``v`` formatted, or '-' for a missing or non-finite value."""
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def mixed_pair(r: dict) -> bool:
    """SR and noSR of scene row ``r`` come from different collections: one a run of this one, the other
    carried over (``(earlier run)``, maybe another machine and an older auto), so their difference was
    not measured side by side."""
    rules = [r["variants"].get(c, {}).get("rules", "") for c in ("gaussian", "none")]
    return all(rules) and len({x.endswith("(earlier run)") for x in rules}) == 2


def summary_lines(rows: list[dict], columns: list[str]) -> list[str]:
    """The one-row-per-scene table: HR PSNR / masked PSNR of bicubic and every variant, set means."""
    names = ["bicubic", *(VARIANTS[c] for c in columns[1:])]
    box = "box" in columns
    lines = ["| scene | set | LR | PSF | views | " + " | ".join(f"{n} HR / masked" for n in names)
             + " | SR - bicubic | SR - noSR |" + (" SR - Vol-SR |" if box else ""),
             "|" + "---|" * (len(names) + 7 + box)]
    for r in rows:
        cells = [f"{fmt(psnr_of(r, c))} / {fmt(psnr_of(r, c, 'psnr_hr_masked'))}" for c in columns]
        sr, none, bic, vol = (psnr_of(r, c) for c in ("gaussian", "none", "bicubic", "box"))
        lines.append(f"| {r['scene']} | {r['set']} | {r.get('lr', '-')} | {fmt(r.get('psf_sigma'), '.3g')} | "
                     f"{r.get('views', '-')} | " + " | ".join(cells) + f" | {fmt(sr - bic, '+.2f')} | "
                     f"{fmt(sr - none, '+.2f')}{MIXED if mixed_pair(r) else ''} |"
                     + (f" {fmt(sr - vol, '+.2f')} |" if box else ""))
    hr, masked = set_means(rows, columns, "psnr_hr"), set_means(rows, columns, "psnr_hr_masked")
    for name in ("tuning", "report"):
        cells = [f"{fmt(hr[name][c])} / {fmt(masked[name][c])}"
                 + (f" (on {hr[name][f'scenes_{c}']})" if c in SUBSET_VARIANTS else "") for c in columns]
        g, n, b = (hr[name].get(c, float("nan")) for c in ("gaussian", "none", "bicubic"))
        vol = [psnr_of(r, "gaussian") - psnr_of(r, "box") for r in rows if r["set"] == name]
        vol = [v for v in vol if math.isfinite(v)]
        mixed = MIXED if any(mixed_pair(r) for r in rows if r["set"] == name) else ""
        lines.append(f"| **{name} mean** ({hr[name]['scenes']} scenes) | {name} | | | | " + " | ".join(cells)
                     + f" | {fmt(g - b, '+.2f')} | {fmt(g - n, '+.2f')}{mixed} |"
                     + (f" {fmt(float(np.mean(vol)) if vol else float('nan'), '+.2f')} |" if box else ""))
    return lines


def detail_lines(rows: list[dict]) -> list[str]:
    """One line per run: every metric of `srvol eval` and the run's cost."""
    lines = ["| scene | variant | HR PSNR | masked PSNR | SSIM | normal MAE (deg) | albedo PSNR | relit PSNR | "
             "train PSNR (LR) | stage-2 swing dB (probe / step) | iterations | train s | parameters | peak RSS GiB | "
             "rules |", "|" + "---|" * 15]
    for r in rows:
        for sr, v in r["variants"].items():
            if "error" in v or v.get("missing"):
                lines.append(f"| {r['scene']} | {VARIANTS[sr]} | {'failed: ' + v['error'] if 'error' in v else 'not run'} "
                             "|" + " |" * 13)
                continue
            lines.append(f"| {r['scene']} | {VARIANTS[sr]} | {fmt(v.get('psnr_hr'))} | {fmt(v.get('psnr_hr_masked'))} | "
                         f"{fmt(v.get('ssim_hr'), '.3f')} | {fmt(v.get('normal_mae_deg'))} | {fmt(v.get('albedo_psnr'))} | "
                         f"{fmt(v.get('relit_psnr'))} | {fmt(v.get('train_psnr'))} | "
                         f"{fmt(v.get('stage2_swing_db'))} / {fmt(v.get('stage2_step_swing_db'))} | "
                         f"{v['iterations']} | "
                         f"{v['train_seconds']:.0f} | {v['parameters'] / 1e6:.2f} M | {fmt(v.get('peak_rss_gib'))} | "
                         f"{v.get('rules', '-')} |")
    return lines


def write_table(rows: list[dict], args, out: Path, command: str) -> str:
    columns = ["bicubic", *args.variants]
    length = f"{args.iters} iterations" if args.iters else f"{args.budget:g} s"
    warm = ("" if args.iters else
            f"; an untimed {WARM_UP_ITERS}-step run of the same flags before each timed one warms torch.compile's "
            "on-disk cache, so no run spends its budget compiling (runs from before that may have)" if args.warm_up
            else "; no warm-up (--no-warm-up): a run may spend its budget compiling")
    lines = [f"# Scene suite: auto preset, {length} per run (2-core CPU)", "",
             f"Each run: OMP_NUM_THREADS={args.threads_per_run}, {args.runs_at_once} run(s) sharing the machine "
             f"at a time (two `bench_suite` processes with disjoint --scenes, then --collect){warm}.", "",
             "HR metrics are means over each scene's held-out test views. bicubic: each test view's own LR image "
             "upsampled bicubically (a 2D reference that sees the test view, which no 3D method is given). Set "
             "means are over the scenes with every column; Vol-SR, run on a subset, is averaged over the scenes it "
             "ran on (`on N`), and `SR - Vol-SR` is taken per scene. `rules` (every run): the beta cap, refining samples, "
             "stage-1 rays, head width and material hash table the run trained with -- `beta free` marks a run of "
             "auto before the cap and the thin-parts rule (`srvol/presets.py`), a rule without `heads 32` a run of "
             "the twice larger model auto derived before, `2 PSF rays` with `material 2^14` a run of the auto "
             "before stage 1's centre rays and the finer material grid, `B-spline SDF` a run of the rule that gives "
             "spread-out silhouettes quadratic B-spline SDF grids (rows without it on such scenes came before it), "
             "`stage 2 SDF x1` a run whose SDF goes on learning in stage 2 (rows without it: frozen, as before), "
             "`L1 saturated at 1` a run whose photometric L1 takes photo pixels at or past white as saturated "
             "(rows without it: linear values, as before), "
             "`(earlier run)` a row carried over from "
             "the table before (its run folder was not on the machine that collected this one); `(mixed)` after "
             "`SR - noSR`: one of the two runs is such an earlier run and the other is not, so the difference "
             "spans collections (maybe machines and versions of auto), not a side-by-side pair. Reproduce: `srvol bench suite "
             + command + "` (resumable; each run's commands below).", "",
             *summary_lines(rows, columns), "", "## Every run", "", *detail_lines(rows), "", "Commands:", ""]
    lines += [f"- {r['scene']} {VARIANTS[sr]}: `{v['command']}`" for r in rows for sr, v in r["variants"].items()]
    text = "\n".join(lines) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    write_result(out / "suite_table.md", text)
    write_result(out / "suite_table.json", json.dumps(rows, indent=1, default=str))
    return text


def write_chart(rows: list[dict], variants: list[str], out: Path) -> None:
    """suite_psnr.png: HR PSNR per scene, bicubic and every variant, tuning and report sets side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = ["bicubic", *variants]
    sets = [s for s in ("tuning", "report") if any(r["set"] == s for r in rows)] or ["tuning"]
    widths = [max(1, sum(r["set"] == s for r in rows)) for s in sets]
    fig, axes = plt.subplots(1, len(sets), figsize=(2 + 1.1 * sum(widths), 4), squeeze=False,
                             gridspec_kw={"width_ratios": widths}, sharey=True)
    bar = 0.8 / len(columns)
    for ax, name in zip(axes[0], sets):
        shown = [r for r in rows if r["set"] == name]
        for k, c in enumerate(columns):
            vals = [psnr_of(r, c) for r in shown]
            ax.bar(np.arange(len(shown)) + (k - (len(columns) - 1) / 2) * bar, np.nan_to_num(vals), bar,
                   label=VARIANTS.get(c, c), color=["C7", "C2", "C0", "C3"][k % 4])
        ax.set_xticks(range(len(shown)), [r["scene"] for r in shown], rotation=30, fontsize=8)
        ax.set_title(f"{name} set")
        ax.grid(alpha=0.3, axis="y")
    finite = [psnr_of(r, c) for r in rows for c in columns if math.isfinite(psnr_of(r, c))]
    if finite:  # dB has no natural zero: start a little below the lowest bar
        axes[0][0].set_ylim(max(0.0, math.floor(min(finite)) - 3), max(finite) + 2)
    axes[0][0].set_ylabel("HR PSNR on held-out views (dB)")
    axes[0][-1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "suite_psnr.png", dpi=110)
    plt.close(fig)


def add_run_arguments(ap: argparse.ArgumentParser) -> None:
    """How long each run trains, how the machine was shared (for the header), --collect, the synth flags
    and the folders: the flags of every benchmark that trains on the suite's scenes (suite, capacity)."""
    ap.add_argument("--budget", type=float, default=600.0, help="training seconds per run (default 600)")
    ap.add_argument("--iters", type=int, default=0, help="train this many iterations instead of --budget (tests)")
    ap.add_argument("--runs-at-once", type=int, default=1, help="for the table's header: how many runs shared the "
                                                                  "machine at a time (default 1)")
    ap.add_argument("--threads-per-run", default=os.environ.get("OMP_NUM_THREADS", "2"),
                    help="for the table's header: each run's OMP_NUM_THREADS (default: this process's)")
    ap.add_argument("--collect", action="store_true", help="train nothing: re-tabulate the runs already in --work")
    ap.add_argument("--no-warm-up", dest="warm_up", action="store_false",
                    help=f"skip the untimed {WARM_UP_ITERS}-step run before each timed one (default: warm "
                         "torch.compile's on-disk cache first, so no timed run spends its budget compiling)")
    ap.add_argument("--synth", default="", help="extra `srvol synth` flags for every scene, e.g. "
                                                "--synth='--lr 24x18 --views 4 --test-views 1' (cached apart)")
    ap.add_argument("--work", type=Path, default=WORK / "suite", help="scenes and runs (default bench/work/suite)")
    ap.add_argument("--results", type=Path, default=RESULTS, help="where the table and chart go (default bench/results)")


def main(argv=None) -> int:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", help="comma list of scenes (default: the tuning and report sets)")
    ap.add_argument("--variants", default="none,gaussian",
                    help="comma list of `srvol train --sr` values: none (noSR), gaussian (auto's SR), box (Vol-SR; "
                         "add it on a subset, e.g. with --scenes) (default none,gaussian)")
    add_run_arguments(ap)
    args = ap.parse_args(argv)
    from srvol.synth.scenes import SCENES

    scenes = args.scenes.split(",") if args.scenes else suite_scenes()
    args.variants = [v for v in args.variants.split(",") if v]
    unknown = [s for s in scenes if s not in SCENES] + [v for v in args.variants if v not in VARIANTS]
    if unknown:
        ap.error(f"unknown scene or variant: {', '.join(unknown)} (scenes: {', '.join(SCENES)}; "
                 f"variants: {', '.join(VARIANTS)})")
    rows = [scene_row(name, args, args.work) for name in scenes]
    command = shlex.join(sys.argv[1:] if argv is None else argv)
    print(write_table(rows, args, args.results, command), flush=True)
    write_chart(rows, args.variants, args.results)
    print(f"wrote {args.results / 'suite_table.md'}, suite_table.json and suite_psnr.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
