"""sbrdf_core._runtime: OpenCV's own thread pool is off where dask's threads run tasks in parallel."""

import os
import subprocess
import sys

import pytest

#: A fresh process: the sbrdf command's start-up settings for a run, then OpenCV imported after (or before) them.
CODE = """
import argparse, sys
if sys.argv[2] == "before":
    import cv2
from sbrdf_core.cli import tune_process
workers = None if sys.argv[3] == "-" else int(sys.argv[3])
tune_process(argparse.Namespace(scheduler=sys.argv[1], workers=workers))
import cv2
print(cv2.getNumThreads())
"""


def _threads(scheduler: str, when: str = "after", workers: str = "-", **env) -> int:
    base = {k: v for k, v in os.environ.items() if k != "OPENCV_FOR_THREADS_NUM"}
    out = subprocess.run([sys.executable, "-c", CODE, scheduler, when, workers], env={**base, **env},
                         capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


def _default() -> int:
    base = {k: v for k, v in os.environ.items() if k != "OPENCV_FOR_THREADS_NUM"}
    out = subprocess.run([sys.executable, "-c", "import cv2; print(cv2.getNumThreads())"], env=base,
                         capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


@pytest.mark.parametrize("when", ["after", "before"])
def test_a_parallel_run_gives_opencv_one_thread(when):
    """Threads or a cluster run tasks in parallel: OpenCV gets one thread whether it was imported before the
    command's start-up settings (setNumThreads) or after them (its environment variable)."""
    assert _threads("threads", when) == 1
    assert _threads("tcp://127.0.0.1:8786", when) == 1


def test_a_sequential_run_keeps_opencvs_pool():
    """One task at a time: OpenCV's own threads are the only parallelism, so they stay."""
    default = _default()
    assert _threads("sync") == default
    assert _threads("threads", workers="1") == default


def test_a_users_setting_is_kept():
    assert _threads("threads", OPENCV_FOR_THREADS_NUM="3") == 3


@pytest.mark.slow  # a dask.distributed cluster of worker processes
def test_cluster_workers_start_with_opencvs_pool_off():
    """A LocalCluster started under CLUSTER_CONFIG passes WORKER_ENV to its worker processes."""
    import dask
    import distributed

    from sbrdf_core.runner import CLUSTER_CONFIG, WORKER_ENV

    assert WORKER_ENV["OPENCV_FOR_THREADS_NUM"] == "1"
    with dask.config.set(CLUSTER_CONFIG), distributed.LocalCluster(
            n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None) as c, \
            distributed.Client(c) as client:
        threads = client.run(lambda: __import__("cv2").getNumThreads())
    assert list(threads.values()) == [1]
