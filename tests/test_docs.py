"""The documentation: the site builds with no warnings, every graph validates, runnable examples run."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from sbrdf_core.graph import load_graph

ROOT = Path(__file__).resolve().parent.parent
GRAPHS = sorted((ROOT / "graphs").glob("*.yaml"))
RUNNABLE = re.compile(r"<!-- runnable -->\s*\n```(python|sh)\n(.*?)\n```", re.S)


def runnable_blocks():
    for page in sorted((ROOT / "docs").rglob("*.md")):
        for k, m in enumerate(RUNNABLE.finditer(page.read_text())):
            yield pytest.param(m.group(1), m.group(2), id=f"{page.relative_to(ROOT / 'docs')}#{k}")


def test_site_builds_without_warnings(tmp_path):
    pytest.importorskip("mkdocs")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    graph_ref = (tmp_path / "site" / "reference" / "graph" / "index.html").read_text()
    for name in ("lafortune", "mcallister8", "gl", "grid-search", "minnaert"):  # built-ins and the example plugin
        assert f"<code>{name}</code>" in graph_ref, name
    for page in (ROOT / "docs" / "reference").glob("*.md"):  # the generated pages replaced the placeholders
        built = (tmp_path / "site" / "reference" / page.stem / "index.html").read_text()
        assert "The site's version of this page is generated" not in built, page.name


LINK = re.compile(r"\]\(([^)\s]+)\)")


def test_links_work_in_the_repository_too():
    """Read on a forge rather than as the site, every relative link of the docs and the README reaches a file in
    the repository: the generated reference pages have placeholders in docs/reference/ (docs/hooks.py)."""
    dead = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
        for target in LINK.findall(text):
            path = target.split("#", 1)[0]
            if path and "://" not in path and not path.startswith("mailto:") and not (page.parent / path).exists():
                dead.append(f"{page.relative_to(ROOT)}: {target}")
    assert not dead, dead


@pytest.mark.parametrize("graph", GRAPHS, ids=[g.name for g in GRAPHS])
def test_every_graph_validates(graph, registry):
    g = load_graph(str(graph), registry)
    assert g.nodes


@pytest.mark.parametrize("lang,code", list(runnable_blocks()))
def test_runnable_examples_run(lang, code, tmp_path):
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    cmd = [sys.executable, "-c", code] if lang == "python" else ["bash", "-euo", "pipefail", "-c", code]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_first_hour_edits_still_apply(registry, tmp_path):
    """docs/first-hour.md edits graphs/demo.yaml with sed and shows a graph of its own: each substitution must
    still match demo.yaml exactly once (a sed that matches nothing would silently run the demo unchanged), and
    the graphs it makes must validate."""
    import shutil

    page = (ROOT / "docs" / "first-hour.md").read_text()
    shutil.copytree(ROOT / "scenes", tmp_path / "scenes")
    (tmp_path / "graphs").mkdir()
    demo = (ROOT / "graphs" / "demo.yaml").read_text()
    seds = re.findall(r"^sed (.*) graphs/demo\.yaml > graphs/([\w-]+\.yaml)$", page, re.M)
    assert len(seds) == 2, seds
    for exprs, out in seds:
        text = demo
        for _sep, old, new in re.findall(r"'s(.)(.*?)\1(.*?)\1'", exprs):
            assert text.count(old) == 1, (out, old)
            text = text.replace(old, new)
        assert text != demo
        (tmp_path / "graphs" / out).write_text(text)
        assert load_graph(str(tmp_path / "graphs" / out), registry).nodes
    own = re.search(r"```yaml\n(name: my-scan\n.*?)```", page, re.S).group(1)
    (tmp_path / "my-scan.yaml").write_text(own)
    assert [n for n in load_graph(str(tmp_path / "my-scan.yaml"), registry).nodes] == \
        ["capture", "register", "reflectance", "fit", "quantize", "render"]


@pytest.mark.slow
def test_first_hour_demo_table_shows_the_chunks_a_run_writes(tmp_path):
    """The first report docs/first-hour.md shows is ``sbrdf run graphs/demo.yaml``'s: the same nodes, each
    with the chunks a run writes (wall times are the machine's, and not compared)."""
    import shutil

    from sbrdf_core.runner import run_graph

    page = (ROOT / "docs" / "first-hour.md").read_text()
    table = re.search(r"```\n(node +status +chunks +wall_s +artifact\n.*?)\ngraph 'demo' done", page, re.S).group(1)
    shown = {row.split()[0]: row.split()[2] for row in table.splitlines()[1:]}
    shutil.copytree(ROOT / "scenes", tmp_path / "scenes")
    (tmp_path / "graphs").mkdir()
    shutil.copy(ROOT / "graphs" / "demo.yaml", tmp_path / "graphs" / "demo.yaml")
    report = run_graph(str(tmp_path / "graphs" / "demo.yaml"), store=str(tmp_path / "runs" / "demo"))
    assert shown == {r.node: f"{r.chunks_written}/{r.chunks_total}" for r in report.nodes}


def test_the_viewer_page_starts_with_a_run_of_what_the_viewer_shows(registry):
    """docs/viewer.md's first commands run a graph and view some of its nodes: the run computes those nodes
    and what they need, and nothing the viewer does not show (a Mip node, renders)."""
    from sbrdf_core.runner import Runner

    block = re.search(r"```sh\n(.*?)```", (ROOT / "docs" / "viewer.md").read_text(), re.S).group(1)
    run = re.search(r"^sbrdf run (\S+)(?: --only ([\w ]+?))?\s*(?:#.*)?$", block, re.M)
    viewed = set(re.findall(r"^sbrdf view runs/[\w-]+/(\w+)", block, re.M))
    graph = load_graph(str(ROOT / run.group(1)), registry)
    ran = Runner._closure(graph, run.group(2).split() if run.group(2) else None)
    assert viewed <= ran
    needed = Runner._closure(graph, sorted(viewed))
    assert ran == needed, f"the run also computes {sorted(ran - needed)}, which the viewer does not show"
