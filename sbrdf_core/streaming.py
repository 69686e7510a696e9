"""Windowed execution: a node's write tasks submitted a few groups at a time.

A scan of thousands of poses gives Register and Reflectance tens of thousands
of tasks.  Submitted at once, the client and the distributed scheduler hold
every one of them (measured: ~16 KB per task in the scheduler's process), so
their memory grows with the scan.  A node whose chunks with different first
indices share no computation (pose blocks; rows of texel tiles) declares
``Output(streamed=True)``; the runner then materializes the graph once, culls
it per window of whole groups (O(window), not O(graph)) and keeps
:data:`WINDOWS_IN_FLIGHT` windows submitted: one computing, the next queued so
workers never wait.  Fewer windows in flight also keep the workers' data
bounded: a window of Register holds one pose block's resampled poses.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

#: Write tasks a window holds at least (whole groups of equal first index).
WINDOW_TASKS = 64
#: Windows submitted at once on a distributed cluster.
WINDOWS_IN_FLIGHT = 2


def first_axis_groups(tasks: list[tuple[tuple[int, ...], Any]]) -> list[list[Any]]:
    """``(chunk index, task)`` pairs -> tasks grouped by first chunk index, in order."""
    groups: dict[int, list] = {}
    for index, task in tasks:
        groups.setdefault(index[0] if index else 0, []).append(task)
    return [groups[k] for k in sorted(groups)]


class WindowedGraph:
    """The write tasks of one node as one low-level graph, cut into windows of whole groups."""

    def __init__(self, groups: list[list[Any]], window_tasks: int | None = None):
        from dask.core import get_dependencies
        from dask.highlevelgraph import HighLevelGraph

        self.groups = groups
        self.window_tasks = window_tasks or WINDOW_TASKS
        self.dsk = dict(HighLevelGraph.merge(*[t.__dask_graph__() for g in groups for t in g]))
        self.deps = {k: get_dependencies(self.dsk, k) for k in self.dsk}

    def windows(self) -> Iterator[tuple[list, dict]]:
        """``(keys, culled graph)`` per window: consecutive groups of at least ``window_tasks`` tasks."""
        keys: list = []
        for group in self.groups:
            keys.extend(t.key for t in group)
            if len(keys) >= self.window_tasks:
                yield keys, self.cull(keys)
                keys = []
        if keys:
            yield keys, self.cull(keys)

    def cull(self, keys: list) -> dict:
        """The part of the graph ``keys`` need."""
        sub: dict = {}
        stack = list(keys)
        while stack:
            k = stack.pop()
            if k not in sub:
                sub[k] = self.dsk[k]
                stack.extend(self.deps[k])
        return sub
