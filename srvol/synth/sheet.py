"""Contact sheet of a synthetic scene: LR input | HR GT | normals | albedo | one relit view."""
from __future__ import annotations

from pathlib import Path

from srvol.data import load_scene
from srvol.sheets import normal_to_rgb, write_sheet


def scene_sheet(scene_dir: Path, out: Path, max_rows: int = 2) -> None:
    scene = load_scene(scene_dir)
    relit = {spec.camera: spec.name for spec in scene.gt.relit()}
    rows = []
    for stem in scene.test[:max_rows]:
        row = [(f"LR input {stem}", scene.views[stem].image)]
        for kind, label in (("hr", "HR GT"), ("normal", "normals"), ("albedo", "albedo")):
            img = scene.gt.image(kind, stem)
            if img is not None:
                row.append((label, normal_to_rgb(img) if kind == "normal" else img))
        if stem in relit:
            row.append((f"relit {relit[stem]}", scene.gt.image("relit", relit[stem])))
        rows.append(row)
    write_sheet(out, rows, encoded_labels=("normals",), title=f"{scene_dir.name}: synthetic ground truth")
