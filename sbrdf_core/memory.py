"""Keep freed memory from piling up in glibc's per-thread heaps.

glibc gives each thread that allocates its own heap ("arena"), up to 8 per
core.  Freed NumPy temporaries stay in the arena that made them, so a run's
resident memory is its live data plus what every arena still holds, and that
grows with the number of tasks a run takes: a 2170-pose Register + Reflectance
(8 GB) held 9 MB more than a 543-pose one (2 GB) with exactly the same live
data (``mallinfo2``; docs/registration.md, Memory).  Two arenas cut the peak
by about 35 MB at no measured cost in time.

:func:`limit_arenas` does this in a running process (``mallopt``); dask
workers, which are fresh processes, read the ``MALLOC_ARENA_MAX`` environment
variable instead (:data:`WORKER_ENV`, docs/cluster.md).  Elsewhere than glibc
both are no-ops.

:data:`CLUSTER_CONFIG` is the dask configuration to start a cluster with
(``dask.config.set(CLUSTER_CONFIG)``): it passes :data:`WORKER_ENV` to the
workers and shortens distributed's developer logs, which otherwise keep the
last 1000 batches of messages, transitions and one-second profiles in the
scheduler and every worker: more tasks or a longer run filled them further
(after a 2170-pose Register + Reflectance the scheduler still held 7 MB of
deserialized graphs in them, after a 543-pose one 2 MB).  It also
queues exactly one root task per worker thread (see below).
"""

from __future__ import annotations

import ctypes
import functools
import os

#: glibc's ``mallopt`` parameter number for the arena limit (malloc.h ``M_ARENA_MAX``).
M_ARENA_MAX = -8
#: Arenas per process: one per worker thread of a 2-core run; more adds held memory, not speed.
ARENAS = 2
#: Environment for dask worker processes (``distributed.nanny.pre-spawn-environ``).
WORKER_ENV = {"MALLOC_ARENA_MAX": str(ARENAS)}
#: Entries kept in distributed's debugging logs (``distributed.admin.low-level-log-length``, default 1000).
LOG_LENGTH = 100
#: dask configuration for a LocalCluster (or any cluster whose processes read it at start-up).
CLUSTER_CONFIG = {
    **{f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in WORKER_ENV.items()},
    "distributed.admin.low-level-log-length": LOG_LENGTH,
    # One queued root task per worker thread, not 1.1: a worker otherwise starts the next
    # root task while the last one's result still waits for its dependents, and holds two.
    # (Streamed nodes, sbrdf_core.streaming, write inside the task and set their own window.)
    "distributed.scheduler.worker-saturation": 1.0,
}


@functools.cache
def limit_arenas(n: int = ARENAS) -> bool:
    """Cap glibc's malloc arenas at ``n`` for threads that allocate from now on; True if applied.

    Respects a ``MALLOC_ARENA_MAX`` the user already set.  Process-wide, so not
    library code's decision: the ``sbrdf`` command calls it once at start-up
    (:func:`sbrdf_core.cli.tune_process`); a program using the runner calls it itself.
    """
    if "MALLOC_ARENA_MAX" in os.environ:
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library, no search
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_ARENA_MAX, int(n)))
