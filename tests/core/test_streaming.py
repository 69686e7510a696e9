"""Streamed nodes: one task per chunk group, a bounded window of them on a cluster.

Register and Reflectance declare ``Output.stream``; the runner fuses each pose
block / texel tile into one task and keeps ``STREAM_GROUPS_PER_THREAD`` per
worker thread in flight.  What keeps a cluster's memory flat in the scan's
size is checked here as the graph property behind it: the scheduler never
holds more tasks than the window (plus the shared data keys), however many
chunks the node writes.
"""

from __future__ import annotations

import dask
import dask.array as da
import numpy as np
import pytest
from dask import delayed
from distributed.diagnostics.plugin import SchedulerPlugin

from sbrdf_core.graph import load_graph
from sbrdf_core.nodes.base import shared
from sbrdf_core.runner import STREAM_GROUPS_PER_THREAD, Runner
from sbrdf_core.streaming import Subgraph, chunk_groups
from tests.conftest import graph_yaml


class Writes:
    """What ``chunk_groups`` needs of the runner's ``ChunkWrites``; writes into a dict."""

    def __init__(self, arrays: dict):
        self.arrays, self.written = arrays, {}
        self.numblocks = {name: arr.numblocks for name, arr in arrays.items()}
        self.pending = [(name, index) for name, arr in arrays.items() for index in np.ndindex(*arr.numblocks)]

    def task(self, name, index):
        def write(block):
            self.written[name, index] = np.array(block)

        return delayed(write, pure=True, name=f"write-{name}-{index}")(self.arrays[name].to_delayed()[index])


def test_a_chunk_group_is_one_task_that_writes_its_chunks():
    big = np.arange(1000.0)
    kernel = da.map_blocks(lambda g, b: g + b.sum(), da.zeros((6, 4), chunks=2), shared(big), dtype=float)
    arrays = {"f": kernel + 1, "ok": kernel > 3, "small": da.from_array(big)}
    writes = Writes(arrays)
    units = list(chunk_groups("n", "tok", writes, 1))
    # a row of blocks of f and ok is one group (2 + 2 chunks); small, chunked otherwise, is its own
    assert sorted(len(n) for _, n in units) == [1, 4, 4, 4]
    for task, _ in units:
        sub = next(a for a in task.dask[task.key].args if isinstance(getattr(a, "value", a), Subgraph))
        graph = getattr(sub, "value", sub).graph
        # the shared array stays a separate key: no fused task carries a copy of it
        assert not any(isinstance(getattr(v, "value", None), np.ndarray) and v.value.size == big.size
                       for v in graph.values())
    dask.compute(*[t for t, _ in units], scheduler="threads")
    written = writes.written
    assert len(written) == 13
    np.testing.assert_array_equal(written["f", (2, 1)], np.full((2, 2), big.sum() + 1))
    np.testing.assert_array_equal(written["ok", (0, 0)], np.ones((2, 2), bool))
    np.testing.assert_array_equal(written["small", (0,)], big)


class MostTasks(SchedulerPlugin):
    """The most tasks the scheduler held at once."""

    def __init__(self, scheduler):
        self.scheduler, self.most = scheduler, 0

    def transition(self, key, start, finish, *args, **kwargs):
        self.most = max(self.most, len(self.scheduler.tasks))


@pytest.mark.slow  # a dask.distributed cluster of worker processes
@pytest.mark.parametrize("node", ["register", "reflectance"])
def test_the_scheduler_holds_a_window_not_the_scan(registry, tmp_path, cluster, node, monkeypatch):
    lc, client = cluster
    # one pose a block, so the number of blocks grows with the poses (the default's 32 MiB
    # blocks only pass 8 at thousands of poses of these 80² texels)
    monkeypatch.setattr("sbrdf_core.nodes.register.pose_block", lambda texels, poses: 1)
    watch = MostTasks(lc.scheduler)
    lc.scheduler.add_plugin(watch, name="most-tasks")
    most = {}
    try:
        # 16 → 48 poses (pose blocks); 4² → 8² texel tiles of 80² texels
        for poses, tile in ((16, 20), (48, 10)):
            g = tmp_path / f"g{poses}.yaml"
            g.write_text(graph_yaml(tmp_path / f"store{poses}", capture={"texels": [80, 80], "poses": poses})
                         .replace("params: {tile: 8}", f"params: {{tile: {tile}}}"))
            runner = Runner(registry, scheduler=client)
            graph = load_graph(str(g), registry)
            before = {"register": ["capture"], "reflectance": ["register"]}[node]
            runner.run(graph, only=before)
            watch.most = 0
            rep = runner.run(graph, only=[node])
            most[poses] = (watch.most, rep[node].chunks_written)
    finally:
        lc.scheduler.remove_plugin(name="most-tasks")
    window = STREAM_GROUPS_PER_THREAD * sum(client.nthreads().values())
    (few, chunks_few), (many, chunks_many) = most[16], most[48]
    assert chunks_many >= 2 * chunks_few and chunks_many > 8 * window  # the node did write many more chunks
    # the groups in flight, plus the shared data keys (capture arrays, plugin, Registration, poses)
    assert many <= window + 12, most
    assert many <= few + 2, most
