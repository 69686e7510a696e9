"""Shared fixtures: small graphs on real zarr stores, and artifact comparison."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
import zarr

from sbrdf_core.artifacts import KINDS
from sbrdf_core.registry import Registry
from sbrdf_core.store import members

SMALL = {"texels": [24, 20], "poses": 12, "noise": 0.01, "seed": 3}


def graph_yaml(store: Path | str, capture: dict | None = None, fit: dict | None = None, name: str = "small") -> str:
    """A full six-node pipeline as YAML text, small enough for unit tests."""
    cap = {**SMALL, **(capture or {})}
    fitp = fit or {"model": "lambert"}
    fmt = lambda d: "{" + ", ".join(f"{k}: {v!r}".replace("'", '"') for k, v in d.items()) + "}"  # noqa: E731
    return textwrap.dedent(f"""\
        name: {name}
        store: {store}
        nodes:
          capture: {{kind: Capture, plugin: synthetic, params: {fmt(cap)}}}
          register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
          reflectance: {{kind: Reflectance, in: {{stack: register}}, params: {{tile: 8}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {fmt(fitp)}}}
          quantize: {{kind: Quantize, plugin: linear, in: {{params: fit}}}}
          render: {{kind: Render, plugin: preview, in: {{material: quantize}}}}
        """)


def synthetic_truth(registry: Registry, **params) -> dict[str, np.ndarray]:
    """Ground-truth parameter maps of the material a ``synthetic`` capture with ``params`` shows."""
    source = registry.create("capture", "synthetic", params)
    source.bind(registry)
    return source.ground_truth()


@pytest.fixture(scope="session")
def registry() -> Registry:
    return Registry()


@pytest.fixture(scope="module")
def cluster():
    """A real 2-worker ``distributed.LocalCluster`` (processes), shared by a test module."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as c, Client(c) as client:
        yield c, client


@pytest.fixture
def write_graph(tmp_path):
    """Write YAML text to a file and return its path."""

    def write(text: str, name: str = "graph.yaml") -> Path:
        p = tmp_path / name
        p.write_text(text)
        return p

    return write


TIMINGS = {a.name for kind in KINDS.values() for a in kind.arrays if a.timing}


def read_store(store: Path | str) -> dict[str, np.ndarray]:
    """Every array of every artifact in a store (markers and wall-clock timings excluded), for comparisons."""
    out = {}
    root = Path(store)
    for node in sorted(p for p in root.iterdir() if (p / "zarr.json").exists()):
        g = zarr.open_group(str(node), mode="r")
        for name, member in members(g):
            if isinstance(member, zarr.Array) and not name.startswith("_done") and name not in TIMINGS:
                out[f"{node.name}/{name}"] = member[...]
    return out


def assert_stores_equal(a, b) -> None:
    A, B = read_store(a), read_store(b)
    assert sorted(A) == sorted(B)
    for key in A:
        assert A[key].dtype == B[key].dtype, key
        assert np.array_equal(A[key], B[key], equal_nan=A[key].dtype.kind == "f"), f"{key} differs"


@pytest.fixture(scope="session")
def gl():
    """The ``gl`` renderer module; skips where no OpenGL 3.3 context can be made through EGL."""
    pytest.importorskip("moderngl")
    from sbrdf_core.errors import SbrdfError
    from sbrdf_render import gl as glmod

    try:
        glmod.context()
    except SbrdfError as e:
        pytest.skip(str(e))
    return glmod


@pytest.fixture
def start_simulator():
    """Start simulators for a test: ``sim = start_simulator(SimulatedPTU, faults=[...])``; all stop at teardown."""
    started = []

    def start(cls, **kwargs):
        sim = cls(**kwargs).start()
        started.append(sim)
        return sim

    yield start
    for sim in started:
        sim.stop()
        assert sim.error is None, f"simulator thread failed: {sim.error!r}"
