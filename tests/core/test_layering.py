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
    """Not even in docstrings (``sbrdf_render.shapes``, ``plugins/sbrdf_rig``): the core finds plugins only
    through entry points.  (Hook names such as ``sbrdf_fitters`` are the contract, not the package.)"""
    names = [p for p in PLUGINS if p != "sbrdf_example"]
    pattern = re.compile(r"\b(" + "|".join(names) + r")[./:]")
    hits = []
    for f in sorted((ROOT / CORE).rglob("*.py")):
        for i, line in enumerate(f.read_text().splitlines(), 1):
            hits += [f"{f.relative_to(ROOT)}:{i} names {m.group(1)}" for m in pattern.finditer(line)]
    assert not hits, "\n".join(hits)
