"""The harness and protocol packages have no import cycles, no library module imports a CLI module, and every
import (Python) and include (C) is one that the folder table of docs/ARCHITECTURE.md allows.

The graph is built statically (ast) over harness/ and protocol/: every `import` and `from ... import` counts,
at module level, inside functions and under `if TYPE_CHECKING:` alike, because each is a dependency of the
design even when Python resolves it late. CLI modules (harness/cli.py, harness/*/cli.py, cli_*.py) only parse
and print: another CLI module may delegate to them (the top-level parser adds the sub-commands' parsers), no other
module may import from them. The console-script entry (pyproject.toml) is not an import.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("harness", "protocol")


def _modules(root: Path) -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is a package __init__)."""
    mods: dict[str, tuple[Path, bool]] = {}
    for pkg in PACKAGES:
        for f in sorted((root / pkg).rglob("*.py")):
            parts = list(f.relative_to(root).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            mods[".".join(parts[:-1] if is_pkg else parts)] = (f, is_pkg)
    return mods


def _known(name: str, mods: dict[str, tuple[Path, bool]]) -> str | None:
    """The innermost module of ours that `name` lives in (a.b.func -> a.b), or None for third-party names."""
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the modules of ours it imports (edges to itself dropped)."""
    mods = _modules(root)
    graph: dict[str, set[str]] = {}
    for name, (path, is_pkg) in mods.items():
        package = name if is_pkg else name.rpartition(".")[0]
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets.update(filter(None, (_known(a.name, mods) for a in node.names)))
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module or ""
                for alias in node.names:
                    # `from pkg import sub` imports the submodule pkg.sub; `from mod import f` imports mod
                    target = _known(f"{source}.{alias.name}", mods) if f"{source}.{alias.name}" in mods \
                        else _known(source, mods)
                    if target:
                        targets.add(target)
        targets.discard(name)
        graph[name] = targets
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def is_cli(module: str) -> bool:
    """cli.py, a package's cli.py, and their helpers named cli_*.py (harness/cli_verdict.py)."""
    name = module.rpartition(".")[2]
    return name == "cli" or name.startswith("cli_")


def _describe(comp: list[str], graph: dict[str, set[str]]) -> str:
    edges = [f"{a} -> {b}" for a in comp for b in sorted(graph[a]) if b in comp]
    return "{" + ", ".join(comp) + "}: " + "; ".join(edges)


def test_graph_sees_every_kind_of_import(tmp_path: Path) -> None:
    pkg = tmp_path / "harness"
    (pkg / "sub").mkdir(parents=True)
    (tmp_path / "protocol").mkdir()
    (tmp_path / "protocol" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from . import b\n")
    (pkg / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from harness.sub.b import X\n")
    (pkg / "sub" / "b.py").write_text("import os\ndef f():\n    from ..c import g\n")
    (pkg / "c.py").write_text("import harness.a\nfrom harness.sub import b\nfrom protocol import nothing\n")
    graph = import_graph(tmp_path)
    assert graph["harness.a"] == {"harness.sub.b"}               # under TYPE_CHECKING
    assert graph["harness.sub.b"] == {"harness.c"}               # relative, inside a function
    assert graph["harness.sub"] == {"harness.sub.b"}             # `from . import b` is the submodule
    assert graph["harness.c"] == {"harness.a", "harness.sub.b", "protocol"}
    assert cycles(graph) == [["harness.a", "harness.c", "harness.sub.b"]]


def test_the_real_graph_is_not_trivial() -> None:
    graph = import_graph()
    assert len(graph) > 100
    assert "protocol.messages" in graph["harness.device.base"]
    assert "harness.campaign.cli" in graph["harness.cli"]


def test_no_import_cycles() -> None:
    graph = import_graph()
    found = cycles(graph)
    assert not found, "import cycles:\n  " + "\n  ".join(_describe(c, graph) for c in found)


@pytest.mark.parametrize("package", PACKAGES)
def test_only_cli_modules_import_cli_modules(package: str) -> None:
    graph = import_graph()
    bad = sorted(f"{a} -> {b}" for a, targets in graph.items() if a.startswith(package) and not is_cli(a)
                 for b in targets if is_cli(b))
    assert not bad, "library modules importing a CLI module (move the helper out of the CLI): " + ", ".join(bad)


def test_no_sub_command_imports_the_top_level_cli() -> None:
    graph = import_graph()
    assert not [a for a, targets in graph.items() if "harness.cli" in targets]


def test_only_harness_paths_knows_the_repository_root() -> None:
    """Paths into the checkout derive from harness/paths.py, not from each module's own __file__."""
    offenders = []
    for f in sorted((ROOT / "harness").rglob("*.py")):
        if f.name == "paths.py":
            continue
        for lineno, line in enumerate(f.read_text().splitlines(), 1):
            if "__file__" in line and ("parents[" in line or ".parent.parent" in line):
                offenders.append(f"{f.relative_to(ROOT)}:{lineno}")
    assert not offenders, "use harness.paths: " + ", ".join(offenders)


# ------------------------------------------------------------------------- the folder table of the docs
ARCHITECTURE = ROOT / "docs" / "ARCHITECTURE.md"
#: the modules that make up the `base` row (beside them, harness/ holds single-module rows like robustness.py)
BASE = {"harness.config", "harness.errors", "harness.kinds", "harness.optional", "harness.options", "harness.paths",
        "harness.flight.data"}


def folder_rules(text: str) -> dict[str, set[str] | None]:
    """The rows of the table under '## Folders': folder -> what it may import (None: anything)."""
    rules: dict[str, set[str] | None] = {}
    section = text.split("\n## Folders", 1)[1].split("\n## ", 1)[0]
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or not cells[0].startswith("`"):
            continue
        key = re.findall(r"`([^`]+)`", cells[0])[0]
        rules[key] = None if cells[2] == "anything" else set(re.findall(r"`([^`]+)`", cells[2]))
    return rules


def unit_of(module: str, root: Path = ROOT) -> str:
    """The table row a Python module belongs to."""
    parts = module.split(".")
    if parts[0] == "protocol":
        return "protocol/"
    if module in BASE:
        return "base"
    if is_cli(module):
        return "cli"
    if len(parts) == 1:
        return "harness"
    if (root / "harness" / parts[1]).is_dir():
        return parts[1] + "/"
    return parts[1] + ".py"


def test_the_folder_table_is_read() -> None:
    rules = folder_rules(ARCHITECTURE.read_text())
    assert rules["protocol/"] == set() and rules["cli"] is None
    assert rules["base"] == {"protocol/"} and "firmware_sim/core/" in rules


def test_every_import_is_one_the_folder_table_allows() -> None:
    rules = folder_rules(ARCHITECTURE.read_text())
    graph = import_graph()
    units = {unit_of(m) for m in graph} - {"harness"}
    assert not units - set(rules), f"add a row to docs/ARCHITECTURE.md for: {sorted(units - set(rules))}"
    bad = sorted(f"{a} -> {b} ({unit_of(a)} -> {unit_of(b)})" for a, targets in graph.items() for b in targets
                 if unit_of(a) not in ("harness", unit_of(b)) and rules[unit_of(a)] is not None
                 and unit_of(b) not in rules[unit_of(a)])  # type: ignore[operator]
    assert not bad, "imports the folder table of docs/ARCHITECTURE.md does not allow:\n  " + "\n  ".join(bad)


def c_includes(root: Path = ROOT) -> list[tuple[str, str, str]]:
    """(file, its folder, the folder of the header it includes) for every quoted #include of firmware_sim/
    whose header is in the tree (generated headers outside it, like the build's model header, are skipped)."""
    fw = root / "firmware_sim"
    sources = [f for f in fw.rglob("*") if f.suffix in (".c", ".h", ".S") and "build" not in f.parts]
    where = {f.name: f"firmware_sim/{f.parent.relative_to(fw).parts[0]}/" for f in sources if f.suffix == ".h"}
    out = []
    for f in sources:
        folder = f"firmware_sim/{f.parent.relative_to(fw).parts[0]}/"
        for name in re.findall(r'^\s*#\s*include\s+"([^"]+)"', f.read_text(errors="replace"), re.M):
            if Path(name).name in where:
                out.append((str(f.relative_to(root)), folder, where[Path(name).name]))
    return out


def test_every_c_include_is_one_the_folder_table_allows() -> None:
    rules = folder_rules(ARCHITECTURE.read_text())
    includes = c_includes()
    assert len(includes) > 50
    folders = {folder for _, folder, _ in includes}
    assert not folders - set(rules), f"add a row to docs/ARCHITECTURE.md for: {sorted(folders - set(rules))}"
    bad = sorted(f"{f} includes a header of {h}" for f, folder, h in includes
                 if rules[folder] is not None and h not in rules[folder])  # type: ignore[operator]
    assert not bad, "includes the folder table of docs/ARCHITECTURE.md does not allow:\n  " + "\n  ".join(bad)



TEST_GROUPS = ("unit", "protocol", "device", "campaign", "mcu")


def test_tests_are_grouped_by_what_they_exercise() -> None:
    """Every test module lives in one of the groups of the folder table (tests/unit, tests/protocol, ...)."""
    tests = ROOT / "tests"
    stray = sorted(str(p.relative_to(ROOT)) for p in tests.rglob("test_*.py")
                   if p.parent.parent != tests or p.parent.name not in TEST_GROUPS)
    assert not stray, f"move into one of tests/{{{','.join(TEST_GROUPS)}}}/: {stray}"
    rules = folder_rules(ARCHITECTURE.read_text())
    assert {f"tests/{g}/" for g in TEST_GROUPS} <= set(rules)
