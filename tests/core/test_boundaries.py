"""Dependency direction of DESIGN.md section 2, checked on the import statements of the sources."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# The core's composition root and the report/demo modules may see every package.
CORE_EXEMPT = {"cli.py", "demo.py"}


def imported_modules(path: Path, root: Path = ROOT) -> set[str]:
    """Absolute module names imported by a source file (``from . import x`` resolved against its package)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = {"srvol": "srvol", "export": "srvol.export", "relight": "srvol.relight"}[path.relative_to(root).parts[0]]
    sub = path.relative_to(root).parts[1:-1]
    here = ".".join([package, *sub])
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            names.add(mod)
            names.update(f"{mod}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "__import__" and node.args \
                and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
            names.add(node.args[0].value)
    return names


def offenders(folder: str, forbidden: tuple[str, ...], exempt=lambda rel: False, root: Path = ROOT) -> list[str]:
    """'file: modules' for each source under ``root/folder`` importing a forbidden module or its children.

    A forbidden name ending in "*" matches every module starting with it (``srvol.train*``).
    """
    def matches(m: str, f: str) -> bool:
        return m.startswith(f[:-1]) if f.endswith("*") else (m == f or m.startswith(f + "."))

    out = []
    for path in sorted((root / folder).rglob("*.py")):
        rel = path.relative_to(root)
        if exempt(rel):
            continue
        bad = sorted(m for m in imported_modules(path, root) if any(matches(m, f) for f in forbidden))
        if bad:
            out.append(f"{rel}: {', '.join(bad)}")
    return out


def core_exempt(rel: Path) -> bool:
    """srvol/cli.py, srvol/demo.py and srvol/report*.py: the modules that compose all packages."""
    return len(rel.parts) == 2 and (rel.name in CORE_EXEMPT or rel.name.startswith("report"))


def test_core_imports_neither_export_nor_relight():
    assert offenders("srvol", ("srvol.export", "srvol.relight", "export", "relight"), core_exempt) == []


def test_export_imports_neither_relight_nor_training():
    if not (ROOT / "export").is_dir():
        pytest.skip("export/ does not exist yet")
    assert offenders("export", ("srvol.relight", "relight", "srvol.train*")) == []


def test_the_scan_sees_relative_and_dynamic_imports(tmp_path):
    # a worked example of what the scanner reports, on a fake tree
    fake = tmp_path / "srvol"
    (fake / "sub").mkdir(parents=True)
    (fake / "sub" / "bad.py").write_text("from .. import relight\nimport srvol.export.usd as u\n"
                                         "m = __import__('srvol.relight.cli')\nimport srvol.training_loop\n")
    (fake / "cli.py").write_text("import srvol.relight\n")
    (fake / "report_html.py").write_text("import srvol.export\n")
    got = offenders("srvol", ("srvol.export", "srvol.relight", "srvol.train*"), core_exempt, root=tmp_path)
    assert got == ["srvol/sub/bad.py: srvol.export.usd, srvol.relight, srvol.relight.cli, srvol.training_loop"]
