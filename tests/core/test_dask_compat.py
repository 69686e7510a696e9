"""The private dask API sbrdf uses (:mod:`sbrdf_core._dask_compat`) exists and behaves as the streaming code assumes.

A dask upgrade that moves or changes these fails here, naming the name, instead of deep inside a streamed run.
"""

from __future__ import annotations

import dask
import numpy as np
from dask import delayed

from sbrdf_core import _dask_compat as compat
from sbrdf_core.nodes.base import shared


def test_names_exist():
    for name in compat.__all__:
        assert getattr(compat, name) is not None, name


def test_datanode_holds_a_value_and_get_sync_runs_a_graph_with_it():
    value = np.arange(3)
    node = compat.DataNode("x", value)
    assert node.value is value
    # a literal DataNode key feeds a task that names it, computed in this thread
    assert compat.get_sync({"x": node, "y": (np.sum, "x")}, ["y"]) == (3,)


def test_merged_graph_keeps_keys_and_shared_values_as_datanodes():
    """What ``streaming.chunk_groups`` relies on: the tasks' own keys survive, and a ``shared`` object is a DataNode
    holding the very object, so a group's graph splits into data keys and computed tasks."""
    obj = np.ones(4)  # a per-pose array, as Register shares its light positions
    data = shared(obj)
    a = delayed(lambda d, i: d[i], pure=True)(data, 1)
    b = delayed(lambda d, i: d[i] * 2, pure=True)(data, 2)
    graph = compat.merged_graph([a, b])
    assert a.key in graph and b.key in graph
    datanodes = {k: v for k, v in graph.items() if isinstance(v, compat.DataNode)}
    assert list(datanodes) == [data.key] and datanodes[data.key].value is obj
    inner = {k: v for k, v in graph.items() if k not in datanodes}
    out = compat.get_sync({**inner, data.key: compat.DataNode(data.key, obj)}, [a.key, b.key])
    assert out == (1.0, 2.0)
    assert dask.compute(a, b) == (1.0, 2.0)
