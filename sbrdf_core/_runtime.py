"""Process tuning for a run: glibc's malloc heaps and one level of thread parallelism.

Process-wide settings are not library code's decision, so nothing in the
engine applies them by itself: the ``sbrdf`` command calls
:func:`tune_process` once at start-up, a program using the runner calls it
itself (:func:`sbrdf_core.runner.tune_process`), and dask worker processes
read the same settings from their environment (:data:`CLUSTER_CONFIG`,
re-exported by :mod:`sbrdf_core.runner`, docs/cluster.md).

Memory
------

Freed memory is kept from piling up in glibc's per-thread heaps.

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

The same call fixes glibc's mmap threshold at :data:`MMAP_THRESHOLD`.  glibc
otherwise raises it to the size of the largest mapped block freed so far (up to
32 MiB), so after the first pose block every block-sized temporary (a block's
zarr encoding buffers, a texel tile) came from the arenas, and the freed memory
they held grew with the number of blocks a node ran, and set the run's peak.
With a fixed threshold such blocks are mapped and returned to the system when
freed, so the arenas stay small whatever the scan's size, while a photograph
and the smaller per-pose temporaries stay in the arenas: a threshold below a
photograph's size would pay page faults on those for every pose.

It also fixes the trim threshold at :data:`TRIM_THRESHOLD`.  Fixing the mmap
threshold leaves glibc's trim threshold at 128 KiB, so freeing a task's
temporaries at the top of a heap gave them back to the system, and the next task
faulted every page in again: a Register pose's photograph, luminance, masks and
maps, and a Fit tile's whole working memory (up to ``FIT_TASK_BYTES``) for every
tile, so the threshold is at least a Fit tile's working memory.  Each heap
keeps at most that much free at its top, whatever the scan, so peaks stay set
by live memory (the fit and Register benchmarks peak alike with a small and a
large threshold).

:data:`CLUSTER_CONFIG` is the dask configuration to start a cluster with
(``dask.config.set(CLUSTER_CONFIG)``): it passes :data:`WORKER_ENV` to the
workers and shortens distributed's developer logs, which otherwise keep the
last 1000 batches of messages, transitions and one-second profiles in the
scheduler and every worker: more tasks or a longer run filled them further
(after a 2170-pose Register + Reflectance the scheduler still held 7 MB of
deserialized graphs in them, after a 543-pose one 2 MB).  It also
queues exactly one root task per worker thread (see below).

Threads
-------

OpenCV parallelises its calls (``remap``, ``detectMarkers``, colour
transforms, ...) on a pthreads pool as large as the machine.  Called from
dask's worker threads, every task then starts as many more threads: on 2
cores, 2 tasks x 2 OpenCV threads, and OpenCV's workers spin a while before
they sleep, so the extra threads add CPU time and no speed: Register on a
benchmark capture under dask's threaded scheduler took more wall and CPU time
with OpenCV's pool than without it.

:func:`single_level` turns the pool off for a process whose runs execute tasks
in parallel: the ``sbrdf`` command calls it at start-up
(:func:`tune_process`) unless the run is sequential (``--scheduler
sync`` or ``--workers 1``), where OpenCV's own threads are the only
parallelism.  Dask worker processes read :data:`LIBRARY_ENV` instead
(:data:`WORKER_ENV`, docs/cluster.md).  A value the user set is
kept.  numba's kernels are left alone: the compiled fitters make their threads
wait passively (``OMP_WAIT_POLICY``), and one numba thread per task measured no
faster under the runner.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import os
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import argparse

logger = logging.getLogger("sbrdf_core.runtime")

#: Environment that keeps libraries' own thread pools to one thread, read when they start (OpenCV: at import).
LIBRARY_ENV = {"OPENCV_FOR_THREADS_NUM": "1"}


#: glibc's ``mallopt`` parameter number for the arena limit (malloc.h ``M_ARENA_MAX``).
M_ARENA_MAX = -8
#: Arenas per process: one per worker thread of a 2-core run; more adds held memory, not speed.
ARENAS = 2
#: glibc's ``mallopt`` parameter number for the mmap threshold (malloc.h ``M_MMAP_THRESHOLD``).
M_MMAP_THRESHOLD = -3
#: Allocations from this size on are mapped (and unmapped when freed), fixed: above a photograph, below a block.
MMAP_THRESHOLD = 4 << 20
#: glibc's ``mallopt`` parameter number for the trim threshold (malloc.h ``M_TRIM_THRESHOLD``).
M_TRIM_THRESHOLD = -1
#: Free memory a heap keeps at its top rather than give back: a Fit task's working memory, fixed.
TRIM_THRESHOLD = 128 << 20
#: Environment for dask worker processes (``distributed.nanny.pre-spawn-environ``): these malloc settings, and
#: OpenCV's pool off, since a worker's threads are the parallelism (:data:`LIBRARY_ENV`).
WORKER_ENV = {"MALLOC_ARENA_MAX": str(ARENAS), "MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD),
              "MALLOC_TRIM_THRESHOLD_": str(TRIM_THRESHOLD), **LIBRARY_ENV}
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
    """Cap glibc's malloc arenas at ``n`` for threads that allocate from now on, and fix
    the mmap and trim thresholds at :data:`MMAP_THRESHOLD` and :data:`TRIM_THRESHOLD`; True
    if the arena cap was applied.

    Respects a ``MALLOC_ARENA_MAX``, ``MALLOC_MMAP_THRESHOLD_`` or ``MALLOC_TRIM_THRESHOLD_``
    the user already set.
    Process-wide, so not library code's decision: the ``sbrdf`` command calls it once at
    start-up (:func:`tune_process`); a program using the runner calls it itself.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library, no search
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    if "MALLOC_MMAP_THRESHOLD_" not in os.environ:
        mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ:
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    if "MALLOC_ARENA_MAX" in os.environ:
        return False
    return bool(mallopt(M_ARENA_MAX, int(n)))


def single_level() -> None:
    """Give OpenCV one thread in this process (dask's threads are the parallelism), unless the user set
    ``OPENCV_FOR_THREADS_NUM``.

    The environment variable covers an OpenCV imported later; ``setNumThreads`` the one loaded now.  OpenCV
    is imported here either way, so the result does not depend on what happened to be imported before.
    """
    for name, value in LIBRARY_ENV.items():
        if name in os.environ:
            continue
        os.environ[name] = value
        import cv2

        cv2.setNumThreads(int(value))


#: ``--scheduler`` values that run one task at a time.
SEQUENTIAL = ("sync", "synchronous", "single-threaded")


def tune_process(args: argparse.Namespace | None = None) -> None:
    """Process-wide settings for a run, made once, before any dask thread starts.

    glibc's malloc arenas are capped (:func:`limit_arenas`): each dask thread
    would otherwise keep its own heap of freed temporaries.  A run that
    executes tasks in parallel (``args.scheduler`` other than sync, and not
    ``args.workers == 1``) gives OpenCV one thread (:func:`single_level`):
    dask's threads are the parallelism.  Without ``args`` only the arenas are
    capped.
    """
    if limit_arenas():
        logger.debug("malloc arenas capped for this process")
    scheduler = getattr(args, "scheduler", None)
    if scheduler is not None and scheduler not in SEQUENTIAL and getattr(args, "workers", None) != 1:
        single_level()
        logger.debug("OpenCV's thread pool off: dask's %s scheduler runs tasks in parallel", scheduler)
