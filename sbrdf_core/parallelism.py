"""One level of parallelism, dask's: no library pool inside a task when dask already runs a task per core.

OpenCV parallelises its calls (``remap``, ``detectMarkers``, colour
transforms, ...) on a pthreads pool as large as the machine.  Called from
dask's worker threads, every task then starts as many more threads: on 2
cores, 2 tasks x 2 OpenCV threads, and OpenCV's workers spin a while before
they sleep, so the extra threads add CPU time and no speed: Register on a
benchmark capture under dask's threaded scheduler took more wall and CPU time
with OpenCV's pool than without it.

:func:`single_level` turns the pool off for a process whose runs execute tasks
in parallel: the ``sbrdf`` command calls it at start-up
(:func:`sbrdf_core.cli.tune_process`) unless the run is sequential (``--scheduler
sync`` or ``--workers 1``), where OpenCV's own threads are the only
parallelism.  Dask worker processes read :data:`LIBRARY_ENV` instead
(``sbrdf_core.memory.WORKER_ENV``, docs/cluster.md).  A value the user set is
kept.  numba's kernels are left alone: the compiled fitters make their threads
wait passively (``OMP_WAIT_POLICY``), and one numba thread per task measured no
faster under the runner.
"""

from __future__ import annotations

import os
import sys

__all__ = ["LIBRARY_ENV", "single_level"]

#: Environment that keeps libraries' own thread pools to one thread, read when they start (OpenCV: at import).
LIBRARY_ENV = {"OPENCV_FOR_THREADS_NUM": "1"}


def single_level() -> None:
    """Give OpenCV one thread in this process (dask's threads are the parallelism), unless the user set
    ``OPENCV_FOR_THREADS_NUM``.  Before OpenCV is imported this is its environment variable; after, its
    ``setNumThreads``."""
    for name, value in LIBRARY_ENV.items():
        if name in os.environ:
            continue
        os.environ[name] = value
        cv2 = sys.modules.get("cv2")
        if cv2 is not None and hasattr(cv2, "setNumThreads"):
            cv2.setNumThreads(int(value))
