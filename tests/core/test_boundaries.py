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


def import_graph(folder: str, root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the modules of the same package it imports (lazy imports inside functions count:
    a cycle hidden in a function is still a cycle)."""
    package = {"srvol": "srvol", "export": "srvol.export", "relight": "srvol.relight"}[folder]
    modules = {}
    for path in sorted((root / folder).rglob("*.py")):
        rel = path.relative_to(root / folder).with_suffix("")
        parts = [p for p in rel.parts if p != "__init__"]
        modules[".".join([package, *parts])] = path
    graph = {}
    for name, path in modules.items():
        imported = imported_modules(path, root)
        graph[name] = {m for m in modules if m != name and m != package and m in imported}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import cycle as [a, b, ..., a], or [] when the graph has none (depth-first search)."""
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done
    path: list[str] = []

    def visit(node: str) -> list[str]:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        state[node] = 2
        path.pop()
        return []

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return []


def test_find_cycle_on_worked_examples():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


@pytest.mark.parametrize("folder", ["srvol", "export", "relight"])
def test_no_import_cycle(folder):
    assert find_cycle(import_graph(folder)) == []


def test_readers_of_a_run_import_its_config_not_the_training_loop():
    """eval, report and the composition root read config.json through srvol.config."""
    for name in ("cli.py", "report.py", "evaluate.py", "checkpoint.py"):
        assert not any(m == "srvol.train" or m.startswith("srvol.train.")
                       for m in imported_modules(ROOT / "srvol" / name)), name


MAX_LINES = 400


def test_no_core_module_is_over_400_lines():
    long = {str(p.relative_to(ROOT)): n for p in sorted((ROOT / "srvol").rglob("*.py"))
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}
