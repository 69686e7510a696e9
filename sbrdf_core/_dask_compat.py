"""Every private dask name sbrdf uses, in one place.

Streamed nodes (:mod:`sbrdf_core.streaming`) fuse a chunk group's tasks into
one task that runs them inside a worker.  That needs three things dask does not
export as public API:

- ``dask._task_spec.DataNode``: how a graph holds a literal value (the shared
  data keys of ``nodes.base.shared``); a fused group's graph is split into its
  data keys (sent once per worker) and its computed tasks by this type;
- ``dask.base.collections_to_expr``: the one merged graph of a list of
  collections, keys unchanged (no optimisation: outputs slicing one kernel must
  keep sharing its key);
- ``dask.local.get_sync``: run a graph in the calling thread (inside the worker task).

Checked against dask and distributed 2026.8.0, pyproject's lower bound (the
release streaming was written and measured on).
``tests/core/test_dask_compat.py`` checks that the names exist and behave as
used here, so a dask upgrade that moves them fails there, not deep in a run.
"""

from __future__ import annotations

from dask._task_spec import DataNode
from dask.base import collections_to_expr
from dask.local import get_sync

__all__ = ["DataNode", "collections_to_expr", "get_sync", "merged_graph"]


def merged_graph(collections: list) -> dict:
    """The merged, unoptimised graph of ``collections`` as a plain dict (key -> task or :class:`DataNode`)."""
    return dict(collections_to_expr(collections, True).__dask_graph__())
