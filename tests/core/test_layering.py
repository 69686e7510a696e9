"""Who may import whom (docs/architecture.md): core <- library layer <- plugins, and no plugin imports another.

Checked on the source, every ``import`` statement including those inside
functions, so a plugin cannot reach around the registry at run time.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CORE, LIB = "sbrdf_core", "sbrdf_lib"
PLUGIN_DIRS = sorted(p for p in (ROOT / "plugins").iterdir() if (p / "__init__.py").exists())
EXAMPLE = ROOT / "docs" / "examples" / "sbrdf-example-plugin" / "sbrdf_example"
PLUGINS = {p.name: p for p in PLUGIN_DIRS} | {"sbrdf_example": EXAMPLE}
PACKAGES = {CORE: ROOT / CORE, LIB: ROOT / LIB, **PLUGINS}
OURS = set(PACKAGES)


def imported(path: Path) -> list[tuple[int, str]]:
    """Top-level package of every absolute import in a file, with its line."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module.split(".")[0]))
    return out


def allowed(package: str) -> set[str]:
    if package == CORE:
        return {CORE}
    if package == LIB:
        return {CORE, LIB}
    return {CORE, LIB, package}


CASES = [(pkg, f) for pkg, d in PACKAGES.items() if d.exists() for f in sorted(d.rglob("*.py"))]


@pytest.mark.parametrize("package,path", CASES, ids=[str(f.relative_to(ROOT)) for _, f in CASES])
def test_imports_follow_the_layering(package, path):
    bad = [f"{path.relative_to(ROOT)}:{line} imports {mod}" for line, mod in imported(path)
           if mod in OURS and mod not in allowed(package)]
    assert not bad, "\n".join(bad) + f"\n{package} may import only {sorted(allowed(package))}"


def test_the_rule_catches_a_plugin_importing_another(tmp_path):
    f = tmp_path / "x.py"
    f.write_text("def f():\n    from sbrdf_render.gl import context\n")
    assert [mod for _, mod in imported(f) if mod not in allowed("sbrdf_envmap")] == ["sbrdf_render"]


def test_the_core_names_no_plugin():
    """Not even in docstrings (``sbrdf_render.gl``, ``plugins/sbrdf_devices``): the core finds plugins only
    through entry points.  (Hook names such as ``sbrdf_fitters`` are the contract, not the package.)"""
    names = [p for p in PLUGINS if p != "sbrdf_example"]
    pattern = re.compile(r"\b(" + "|".join(names) + r")[./:]")
    hits = []
    for f in sorted((ROOT / CORE).rglob("*.py")):
        for i, line in enumerate(f.read_text().splitlines(), 1):
            hits += [f"{f.relative_to(ROOT)}:{i} names {m.group(1)}" for m in pattern.finditer(line)]
    assert not hits, "\n".join(hits)


def core_import_graph() -> dict[str, set[str]]:
    """``{module: core modules it imports}`` over every import statement, those under ``TYPE_CHECKING`` and
    inside functions included: a cycle of annotations still ties two modules together for a reader."""
    mods = {}
    for f in (ROOT / CORE).rglob("*.py"):
        parts = list(f.relative_to(ROOT).with_suffix("").parts)
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f

    def resolve(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    edges: dict[str, set[str]] = {m: set() for m in mods}
    for m, f in mods.items():
        package = m if f.name == "__init__.py" else m.rpartition(".")[0]
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = package.split(".")[: len(package.split(".")) - node.level + 1] if node.level else []
                mod = ".".join(base + [node.module] if node.module else base)
                targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
            else:
                continue
            edges[m] |= {r for t in targets if t.startswith(CORE) and (r := resolve(t)) and r != m}
    return edges


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_the_core_has_no_import_cycles():
    """A reader can take the core's modules in an order where each names only those before it."""
    assert cycles(core_import_graph()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_architecture_page_draws_the_cores_layers_as_they_are():
    """docs/architecture.md draws the core in rows; a module there imports only its own row or rows under it."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = re.search(r"```text\n( command line.*?)```", text, re.S).group(1)
    rows: list[list[str]] = []
    for line in block.splitlines():
        if line[:17].strip():
            rows.append([])
        rows[-1] += [f"{CORE}." + m.strip().rstrip("/").replace("/", ".") for m in line[17:50].split(",") if m.strip()]

    def row(module: str) -> int | None:
        """The row of the longest drawn name that is the module or a package holding it."""
        found = [(len(m), i) for i, r in enumerate(rows) for m in r if module == m or module.startswith(m + ".")]
        return max(found)[1] if found else None

    edges = core_import_graph()
    upward = [f"{a} -> {b}" for a, bs in edges.items() for b in bs
              if row(a) is not None and row(b) is not None and row(b) < row(a)]
    assert not upward, "\n".join(upward)
    assert row(f"{CORE}.types") is not None and row(f"{CORE}.store._artifact") is not None
