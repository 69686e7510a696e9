"""Chunk groups: the unit a streamed node is computed in (see :attr:`Output.stream`).

A node whose chunks at different positions share no work is not handed to
dask as one graph of per-chunk tasks.  Its chunks are grouped by position on
the first ``stream`` chunk axes (Register: a pose block; Reflectance: a texel
tile), and each group becomes **one task** that computes the group's kernel
and writes its chunks.  Two things follow:

* A worker never holds a finished block waiting for the scheduler to send its
  write tasks, so it holds one block per thread.  With separate write tasks a
  thread starts the next block meanwhile.
* The runner submits a bounded window of groups at a time.  So the scheduler
  and the client hold state for ``window`` tasks, not for every chunk of the
  scan, and their memory does not grow with its size.

The data a graph carries as one key (``nodes.base.shared``: a Registration, a
zarr array handle, every pose's light position) stays a separate key, which
each worker fetches once.  Only the computed tasks are fused.

The private dask API this needs is imported from :mod:`sbrdf_core._dask_compat` only.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol


class ChunkWrites(Protocol):
    """What :func:`chunk_groups` needs of the chunks a node still has to write.

    The runner's :class:`~sbrdf_core.runner.ChunkWrites` is one; a test's
    stand-in that writes into a dict is another.
    """

    #: ``(output, chunk index)`` pairs still to write, in order.
    pending: list[tuple[str, tuple]]
    #: Each output's number of chunks along every axis.
    numblocks: dict[str, tuple[int, ...]]

    def task(self, name: str, index: tuple) -> Any:
        """The (dask Delayed) task that computes chunk ``index`` of output ``name`` and writes it."""
        ...


class Subgraph:
    """Tasks to run inside one worker task. A plain holder, so dask doesn't traverse it."""

    __slots__ = ("graph", "keys")

    def __init__(self, graph: dict, keys: list):
        self.graph, self.keys = graph, keys


def run_group(sub: Subgraph, data_keys: Sequence, *data: Any) -> int:
    """Worker side: compute one chunk group's tasks in order; returns the chunks written."""
    from ._dask_compat import DataNode, get_sync

    get_sync({**sub.graph, **{k: DataNode(k, v) for k, v in zip(data_keys, data)}}, list(sub.keys))
    return len(sub.keys)


def chunk_groups(node: str, token: str, writes: ChunkWrites, axes: int, data: Callable[[Any, Any], Any] | None = None,
                 attempt: int = 0) -> Iterator[tuple[Any, list]]:
    """Yield ``(task, chunks)``: one fused task per group of ``writes.pending`` chunks,
    and the ``(output, chunk index)`` pairs it writes.

    ``writes`` (:class:`ChunkWrites`, the runner's in a run) gives the
    ``(output, chunk index)`` pairs still to write, their outputs' ``numblocks``,
    and ``task(output, index)``, which makes a chunk's write task.  Outputs
    chunked alike on the streamed axes group together (radiance and valid of a
    pose block); the others (the small per-pose arrays, one chunk each) form
    groups of their own, so a block's task stays the same size whatever the
    number of poses.  Groups are made lazily, in order, so the client builds a
    group's tasks and graph only when the window has room for it.

    ``data(key, value)`` gives what a group depends on for a shared data key.
    By default it is that key in the group's own graph. On a cluster, the
    runner scatters each value once (a future) instead, because a key in a
    graph is sent again with every submission. Groups sent again after that
    data was lost (``attempt`` > 0) get new keys: the scheduler may still hold
    the lost ones.
    """
    from dask import delayed
    from dask.delayed import Delayed

    from ._dask_compat import DataNode, merged_graph

    resolve = data or (lambda k, v: Delayed(k, {k: DataNode(k, v)}))
    by_group: dict[tuple, list] = {}
    for name, index in writes.pending:
        by_group.setdefault((tuple(writes.numblocks[name][:axes]), tuple(index[:axes])), []).append((name, index))
    for group in sorted(by_group, key=lambda g: (g[1], g[0])):
        chunks = by_group.pop(group)
        names = [name for name, _ in chunks]
        tasks = [writes.task(name, index) for name, index in chunks]
        graph = merged_graph(tasks)
        shared = {k: v for k, v in graph.items() if isinstance(v, DataNode)}
        inner = {k: v for k, v in graph.items() if k not in shared}
        key = f"write-{node}-{names[0]}-{'.'.join(map(str, group[1]))}-{getattr(writes, 'key_id', token)}"
        key += f"-{attempt}" if attempt else ""
        deps = [resolve(k, v.value) for k, v in shared.items()]
        fused = delayed(run_group, pure=True, traverse=False)
        yield fused(Subgraph(inner, [t.key for t in tasks]), list(shared), *deps, dask_key_name=key), chunks
