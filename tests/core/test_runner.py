"""The runner: end to end, caching, resume after SIGKILL, distributed equality, lost workers."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from sbrdf_core.errors import ArtifactError, RunError
from sbrdf_core.graph import load_graph
from sbrdf_core.runner import Runner
from sbrdf_core.store import open_artifact

from ..conftest import assert_stores_equal, graph_yaml, read_store, synthetic_truth


def run(write_graph, registry, store, name="graph.yaml", **kw):
    capture = kw.pop("capture", None)
    fit = kw.pop("fit", None)
    g = load_graph(write_graph(graph_yaml(store, capture, fit), name), registry)
    return Runner(registry, **kw).run(g)


def test_pipeline_end_to_end(write_graph, registry, tmp_path):
    rep = run(write_graph, registry, tmp_path / "s")
    assert [r.status for r in rep.nodes] == ["computed"] * 6
    fit = open_artifact(str(tmp_path / "s" / "fit"))
    assert fit.kind == "ParamMaps" and fit.complete
    prov = fit.provenance
    assert prov["node"] == "fit" and prov["plugin"]["name"] == "lm" and prov["plugin"]["version"]
    assert prov["inputs"]["samples"]["token"] == open_artifact(str(tmp_path / "s" / "reflectance")).token
    assert prov["parameters"]["model"] == "lambert"
    # the Lambertian fit recovers the synthetic material to the noise level
    truth = synthetic_truth(registry, texels=[24, 20], poses=12, noise=0.01, seed=3)["rho_d"]
    rho = fit.read("params/rho_d")
    assert rho.shape == (20, 24, 3)
    assert np.abs(rho - truth).max() < 0.01 * truth.max() + 1e-4
    assert (fit.read("samples") == 12).all()
    image = open_artifact(str(tmp_path / "s" / "render")).read("image")
    assert image.shape == (20, 24, 3) and np.isfinite(image).all() and image.max() > 0
    assert (tmp_path / "s" / "render" / "image.exr").exists() and (tmp_path / "s" / "render" / "image.png").exists()


def test_unchanged_nodes_are_not_recomputed(write_graph, registry, tmp_path):
    store = tmp_path / "s"
    run(write_graph, registry, store)
    stamp = {p: p.stat().st_mtime_ns for p in store.rglob("*") if p.is_file()}
    rep = run(write_graph, registry, store)
    assert [r.status for r in rep.nodes] == ["cached"] * 6
    assert stamp == {p: p.stat().st_mtime_ns for p in store.rglob("*") if p.is_file()}
    # change a fit parameter: upstream stays cached, fit and everything after it recompute
    rep = run(write_graph, registry, store, fit={"model": "lambert", "iterations": 7})
    assert [r.status for r in rep.nodes] == ["cached"] * 3 + ["computed"] * 3


def test_incomplete_artifact_is_not_consumed(write_graph, registry, tmp_path):
    store = tmp_path / "s"
    run(write_graph, registry, store)
    import zarr

    zarr.open_group(str(store / "reflectance"), mode="r+").attrs["complete"] = False
    with pytest.raises(ArtifactError, match="incomplete"):
        open_artifact(str(store / "reflectance"))


def test_resume_after_sigkill_gives_identical_result(write_graph, registry, tmp_path):
    slow = {"poses": 40, "pose_delay_s": 0.1}
    graph = write_graph(graph_yaml(tmp_path / "killed", slow), "killed.yaml")
    proc = subprocess.Popen([sys.executable, "-m", "sbrdf_core.cli", "run", "-q", str(graph)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    markers = tmp_path / "killed" / "capture" / "_done" / "images" / "c"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(list(markers.glob("*/*/*/*"))) < 6:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    written = len(list(markers.glob("*/*/*/*")))
    assert 6 <= written < 40
    with pytest.raises(ArtifactError, match="incomplete"):
        open_artifact(str(tmp_path / "killed" / "capture"))

    rep = run(write_graph, registry, tmp_path / "killed", "killed.yaml", capture=slow)
    assert rep["capture"].status == "resumed"
    assert rep["capture"].chunks_resumed >= written  # images and valid markers of finished poses
    assert rep["capture"].chunks_written < rep["capture"].chunks_total
    run(write_graph, registry, tmp_path / "clean", "clean.yaml", capture=slow)
    assert_stores_equal(tmp_path / "killed", tmp_path / "clean")


@pytest.mark.slow  # a dask.distributed cluster of worker processes
def test_distributed_run_is_identical_to_local(write_graph, registry, tmp_path, cluster):
    _, client = cluster
    run(write_graph, registry, tmp_path / "local")
    rep = run(write_graph, registry, tmp_path / "dist", "dist.yaml", scheduler=client.scheduler.address)
    assert all(r.status == "computed" for r in rep.nodes)
    assert_stores_equal(tmp_path / "local", tmp_path / "dist")


@pytest.mark.slow  # a dask.distributed cluster of worker processes
@pytest.mark.parametrize("victim_node", ["capture", "register"])  # per-chunk tasks; streamed chunk groups
def test_losing_a_worker_mid_run_loses_nothing(write_graph, registry, tmp_path, cluster, victim_node):
    _, client = cluster
    client.wait_for_workers(2, timeout=60)  # the other case's victim is back
    slow = {"poses": 30, "pose_delay_s": 0.05}
    killed = []

    def progress(node, done, total):
        if node == victim_node and done >= 8 and not killed:
            pids = client.run(os.getpid)
            victim = sorted(pids.values())[0]
            os.kill(victim, signal.SIGKILL)
            killed.append(victim)

    run(write_graph, registry, tmp_path / "local", capture=slow)
    rep = run(write_graph, registry, tmp_path / "dist", "dist.yaml", capture=slow, scheduler=client, progress=progress)
    assert killed, "the worker was never killed"
    assert rep[victim_node].chunks_written == rep[victim_node].chunks_total
    assert_stores_equal(tmp_path / "local", tmp_path / "dist")


@pytest.mark.slow  # a dask.distributed cluster of worker processes
def test_a_worker_dying_with_the_only_copy_of_scattered_data_loses_nothing(write_graph, registry, tmp_path, caplog):
    """Register's shared data is scattered to the workers present; one that joins later has
    no copy. Kill the one that does: the scheduler cannot recompute scattered data, so the
    runner scatters it again and sends the groups that were lost."""
    from distributed import Client, LocalCluster

    slow = {"poses": 30, "pose_delay_s": 0.05}
    run(write_graph, registry, tmp_path / "local", capture=slow)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as c, \
            Client(c) as client:
        killed = []

        def progress(node, done, total):
            if node == "register" and done >= 4 and not killed:
                first = list(client.run(os.getpid).values())
                c.scale(2)
                client.wait_for_workers(2, timeout=60)
                os.kill(first[0], signal.SIGKILL)
                killed.append(first[0])

        with caplog.at_level("WARNING", logger="sbrdf_core.runner"):
            rep = run(write_graph, registry, tmp_path / "dist", "dist.yaml", capture=slow, scheduler=client,
                      progress=progress)
    assert killed
    assert "scattering its data again" in caplog.text
    assert rep["register"].chunks_written == rep["register"].chunks_total
    assert_stores_equal(tmp_path / "local", tmp_path / "dist")


@pytest.mark.slow  # a dask.distributed cluster of worker processes
def test_no_worker_left_fails_clearly_and_stays_resumable(write_graph, registry, tmp_path):
    from distributed import Client, LocalCluster

    slow = {"poses": 30, "pose_delay_s": 0.05}
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as c, Client(c) as client:
        def progress(node, done, total):
            if done >= 4 and c.workers:
                c.scale(0)

        with pytest.raises(RunError, match="no dask workers left"):
            run(write_graph, registry, tmp_path / "s", capture=slow, scheduler=client, progress=progress, no_worker_timeout=2)
    with pytest.raises(ArtifactError, match="incomplete"):
        open_artifact(str(tmp_path / "s" / "capture"))
    rep = run(write_graph, registry, tmp_path / "s", capture=slow)
    assert rep["capture"].status == "resumed"
    assert read_store(tmp_path / "s")["capture/images"].shape == (30, 20, 24, 3)


class SequentialCapture:
    """A synthetic source that claims to drive hardware: one pose at a time, in order."""

    sequential = True

    def __init__(self, **params):
        from sbrdf_capture.synthetic import SyntheticCapture

        self.inner = SyntheticCapture(**params)
        self.reads = []

    def bind(self, registry):
        self.inner.bind(registry)

    def describe(self):
        return self.inner.describe()

    def read_pose(self, index):
        import threading

        self.reads.append((index, threading.current_thread().name))
        return self.inner.read_pose(index)


@pytest.mark.parametrize("sequential", [False, True])
def test_every_pose_is_read_exactly_once(write_graph, tmp_path, monkeypatch, sequential):
    """Outputs sharing one kernel (images, valid) must not run it twice: a rig would shoot twice."""
    from sbrdf_capture import synthetic
    from sbrdf_core.plugin import PluginSpec, hookimpl
    from sbrdf_core.registry import Registry

    reads = []
    original = synthetic.SyntheticCapture.read_pose
    monkeypatch.setattr(synthetic.SyntheticCapture, "read_pose", lambda self, i: reads.append(i) or original(self, i))
    params = tuple(Registry().get("capture", "synthetic").params)

    class Plug:
        @hookimpl
        def sbrdf_captures(self):
            return [PluginSpec("sequential-synthetic", f"{__name__}:SequentialCapture", params)]

    reg = Registry(extra=[Plug()])
    plugin = "sequential-synthetic" if sequential else "synthetic"
    text = graph_yaml(tmp_path / "s", {"poses": 9}).replace("plugin: synthetic", f"plugin: {plugin}")
    Runner(reg).run(load_graph(write_graph(text), reg), only=["capture"])
    assert sorted(reads) == list(range(9))
    if sequential:
        assert reads == sorted(reads)  # in pose order


def test_store_on_an_fsspec_url(registry):
    """Stores are URLs: the same graph runs on an in-memory fsspec file system."""
    import fsspec

    url = "memory://sbrdf-test/run"
    g = load_graph(graph_yaml(url).replace("texels: [24, 20]", "texels: [8, 6]"), registry)
    try:
        Runner(registry, scheduler="sync").run(g)
        fit = open_artifact(url + "/fit")
        assert fit.complete and fit.read("params/rho_d").shape == (6, 8, 3)
        assert fsspec.filesystem("memory").exists("/sbrdf-test/run/render/image.png")
        assert [r.status for r in Runner(registry, scheduler="sync").run(g).nodes] == ["cached"] * 6
    finally:
        fsspec.filesystem("memory").rm("/sbrdf-test", recursive=True)
