"""A run killed anywhere resumes to the uninterrupted run's arrays.

The child run sends itself the signal at an exact point of one node's
writing (``SBRDF_TEST_KILL_AT``, a test-only hook of :mod:`sbrdf_core.store`):
before its group exists, between the group and its arrays, between two
``create_array`` calls, after its first chunk, with every chunk written but
``complete`` not yet set, and just after it.  SIGKILL leaves whatever was on
disk; SIGTERM kills without Python's cleanup; SIGINT is Ctrl-C (the CLI's
"interrupted" path).  The same graph is then run again, in this process, and
every array of the store must equal the uninterrupted run's.
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys

import pytest

from sbrdf_core.graph import load_graph
from sbrdf_core.runner import Runner

from ..conftest import assert_stores_equal, graph_yaml

NODES = ["capture", "register", "reflectance", "fit", "quantize", "render"]
#: Stage boundaries of a node's writing, in order (the hook points of sbrdf_core.store).
POINTS = ["group", "marker", "array", "markers", "chunk", "complete", "completed"]
SIGNALS = ["SIGKILL", "SIGTERM", "SIGINT"]
QUICK = [("capture", "array", "SIGKILL"), ("fit", "marker", "SIGTERM"), ("quantize", "chunk", "SIGINT")]


@pytest.fixture(scope="module")
def reference(tmp_path_factory, registry):
    """The uninterrupted run's store."""
    root = tmp_path_factory.mktemp("reference")
    g = root / "g.yaml"
    g.write_text(graph_yaml(root / "s"))
    Runner(registry).run(load_graph(g, registry))
    return root / "s"


def _default_sigint() -> None:
    """A child of a background job starts with SIGINT ignored, and Python then raises no KeyboardInterrupt."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def kill_and_resume(tmp_path, registry, reference, node: str, point: str, sig: str) -> None:
    graph = tmp_path / "g.yaml"
    graph.write_text(graph_yaml(tmp_path / "s"))
    env = {**os.environ, "SBRDF_TEST_KILL_AT": f"{node}:{point}:{sig}"}
    child = subprocess.run([sys.executable, "-m", "sbrdf_core.cli", "run", "-q", str(graph)], env=env,
                           capture_output=True, text=True, timeout=300, preexec_fn=_default_sigint)
    expected = {"SIGKILL": -9, "SIGTERM": -15, "SIGINT": 130}[sig]
    assert child.returncode == expected, f"{node}:{point}:{sig} rc {child.returncode}\n{child.stderr[-3000:]}"
    if sig == "SIGINT":
        assert "Traceback" not in child.stderr and "interrupted" in child.stderr, child.stderr[-3000:]
    rep = Runner(registry).run(load_graph(graph, registry))
    before = NODES[:NODES.index(node)] + ([node] if point == "completed" else [])
    assert all(rep[n].status == "cached" for n in before), [(r.node, r.status) for r in rep.nodes]
    assert_stores_equal(tmp_path / "s", reference)


@pytest.mark.parametrize("node, point, sig", QUICK)
def test_a_run_killed_inside_a_nodes_writing_resumes_to_the_same_arrays(tmp_path, registry, reference, node, point, sig):
    kill_and_resume(tmp_path, registry, reference, node, point, sig)


@pytest.mark.slow
@pytest.mark.parametrize("node, point, sig", [c for c in itertools.product(NODES, POINTS, SIGNALS) if c not in QUICK])
def test_a_run_killed_at_every_stage_boundary_resumes(tmp_path, registry, reference, node, point, sig):
    kill_and_resume(tmp_path, registry, reference, node, point, sig)
