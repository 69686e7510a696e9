"""``NodeKind.prepare``: the runner computes what a node needs concrete before ``build``, on the run's scheduler,
with the node's progress, and ``build`` (here through the Register node) finds the results in ``ctx.prepared``."""

from __future__ import annotations

import dask
import dask.array as da
import dask.threaded
import numpy as np
import pytest

from sbrdf_core.errors import RunError
from sbrdf_core.graph import load_graph
from sbrdf_core.plugin import PluginSpec, hookimpl
from sbrdf_core.registry import Registry
from sbrdf_core.runner import Runner
from sbrdf_core.store import open_artifact

from ..conftest import graph_yaml

SEEN: list = []


class PreparedAligned:
    """texel-aligned registration that asks the runner for a lazy array sum and a list of delayed values."""

    params = ()

    def __init__(self):
        from sbrdf_register.texel_aligned import TexelAligned

        self.inner = TexelAligned(max_rms_mm=0.5)

    def prepare(self, capture):
        light = da.from_array(capture.zarr_array("light_pos"), chunks=(2, 3))
        return {"light_sum": light.sum(), "parts": [dask.delayed(int)(i) for i in range(3)]}

    def register(self, capture, prepared=None):
        SEEN.append(prepared)
        return self.inner.register(capture)

    def resample(self, image, valid, pose, registration):
        return self.inner.resample(image, valid, pose, registration)


class BadPrepare(PreparedAligned):
    def prepare(self, capture):
        return {"not_lazy": np.zeros(3)}


class Plug:
    @hookimpl
    def sbrdf_registrations(self):
        return [PluginSpec("prepared-aligned", f"{__name__}:PreparedAligned"),
                PluginSpec("bad-prepare", f"{__name__}:BadPrepare")]


def graph(write_graph, tmp_path, plugin: str, reg: Registry):
    text = graph_yaml(tmp_path / "s", {"poses": 6}).replace("plugin: texel-aligned", f"plugin: {plugin}")
    return load_graph(write_graph(text), reg)


def test_prepare_is_computed_on_the_runs_scheduler_with_progress(write_graph, tmp_path, monkeypatch):
    reg = Registry(extra=[Plug()])
    g = graph(write_graph, tmp_path, "prepared-aligned", reg)

    def threaded(*a, **k):
        raise AssertionError("computed on the threaded scheduler, not the run's")

    monkeypatch.setattr(dask.threaded, "get", threaded)
    calls = []
    SEEN.clear()
    Runner(reg, scheduler="sync", progress=lambda *c: calls.append(c)).run(g, only=["register"])
    (prepared,) = SEEN
    expected = open_artifact(str(tmp_path / "s" / "capture")).read("light_pos").sum()
    assert prepared["light_sum"] == pytest.approx(expected) and prepared["parts"] == [0, 1, 2]
    prep = [c for c in calls if c[0] == "register prepare"]
    assert [c[1:] for c in prep] == [(i, 4) for i in range(1, 5)]  # one array output key and three delayed ones


def test_prepare_must_return_dask_collections(write_graph, tmp_path):
    reg = Registry(extra=[Plug()])
    with pytest.raises(RunError, match="prepare must return dask collections; \\['not_lazy'\\]"):
        Runner(reg, scheduler="sync").run(graph(write_graph, tmp_path, "bad-prepare", reg), only=["register"])
