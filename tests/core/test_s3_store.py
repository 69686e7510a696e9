"""Stores on S3: a local S3 server (moto's server mode) and a distributed.LocalCluster (issue 27).

Storage options reach every process through the environment (docs/cluster.md):
``FSSPEC_S3_ENDPOINT_URL`` and the ``AWS_*`` credentials, set before the
cluster starts so its worker processes inherit them.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

pytest.importorskip("s3fs")
moto_server = pytest.importorskip("moto.server")
distributed = pytest.importorskip("distributed")

#: A moto S3 server and dask.distributed clusters: run with ``-m slow``.
pytestmark = pytest.mark.slow

import fsspec  # noqa: E402
import fsspec.config  # noqa: E402

from sbrdf_core.runner import run_graph  # noqa: E402
from sbrdf_core.store import (  # noqa: E402
    HOLDER_FILE,
    S3Lease,
    StoreBusy,
    StoreLock,
    open_artifact,  # noqa: E402
)

ENV = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1"}


@pytest.fixture(scope="module")
def s3():
    """A moto S3 server on 127.0.0.1; the environment and fsspec's config point s3fs at it."""
    import logging

    logging.getLogger("werkzeug").setLevel(logging.ERROR)
    saved = {k: os.environ.get(k) for k in [*ENV, "FSSPEC_S3_ENDPOINT_URL"]}
    os.environ.update(ENV)
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    endpoint = f"http://{host}:{port}"
    os.environ["FSSPEC_S3_ENDPOINT_URL"] = endpoint
    conf = fsspec.config.conf.setdefault("s3", {})
    old_conf = dict(conf)
    conf["endpoint_url"] = endpoint
    fs = fsspec.filesystem("s3", skip_instance_cache=True)
    fs.mkdir("sbrdf-test")
    yield fs
    server.stop()
    conf.clear()
    conf.update(old_conf)
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@pytest.fixture(scope="module")
def cluster(s3):
    import dask

    from sbrdf_core.runner import CLUSTER_CONFIG

    with dask.config.set(CLUSTER_CONFIG), distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c, \
            distributed.Client(c) as client:
        yield client


def graph_text(store: str) -> str:
    return textwrap.dedent(f"""\
        name: s3-small
        store: {store}
        nodes:
          a: {{kind: SampleModel, params: {{model: lambert, texels: [64, 32], poses: 1100}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: a}}, params: {{model: lambert}}}}
          q: {{kind: Quantize, plugin: linear, in: {{params: fit}}}}
        """)


ARRAYS = {"a": None, "fit": None, "q": None}


def arrays_of(store: str) -> dict:
    out = {}
    for node in ARRAYS:
        art = open_artifact(f"{store}/{node}")
        for name in art.names():
            if "time" in name:  # wall-clock measurements differ run to run
                continue
            out[f"{node}/{name}"] = art.read(name)
    return out


def assert_same(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.fixture(scope="module")
def local_arrays(tmp_path_factory):
    store = str(tmp_path_factory.mktemp("local") / "s")
    run_graph(graph_text(store), progress=False)
    return arrays_of(store)


# -- the lock ----------------------------------------------------------------


def test_s3_lock_refuses_a_second_run_naming_the_holder_and_is_released(s3):
    store = "s3://sbrdf-test/lock1"
    with StoreLock(store, False, "graph 'one'") as first:
        assert isinstance(first.lock, S3Lease)
        with pytest.raises(StoreBusy, match=rf"in use by pid {os.getpid()} on .*graph 'one'"):
            with StoreLock(store, False, "graph 'two'"):
                pass
        with pytest.raises(StoreBusy, match=r"waited 1.5 s"):
            with StoreLock(store, 1.5, "graph 'two'"):
                pass
    assert not s3.exists(f"sbrdf-test/lock1/{HOLDER_FILE}")
    with StoreLock(store, False, "graph 'three'"):
        assert s3.exists(f"sbrdf-test/lock1/{HOLDER_FILE}")


def test_s3_lock_of_a_dead_process_or_an_expired_lease_is_taken_over(s3, monkeypatch):
    import json

    store, path = "s3://sbrdf-test/lock2", f"sbrdf-test/lock2/{HOLDER_FILE}"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    s3.pipe(path, json.dumps({"pid": dead.pid, "host": socket.gethostname(), "expires": time.time() + 999}).encode())
    with StoreLock(store, False, "after a killed run"):
        assert json.loads(s3.cat(path))["pid"] == os.getpid()
    s3.pipe(path, json.dumps({"pid": 1, "host": "elsewhere", "expires": time.time() - 1}).encode())
    with StoreLock(store, False, "after an expired lease"):
        pass
    s3.pipe(path, json.dumps({"pid": 1, "host": "elsewhere", "expires": time.time() + 999}).encode())
    with pytest.raises(StoreBusy, match="pid 1 on elsewhere"):
        with StoreLock(store, False):
            pass
    s3.rm(path)


def test_s3_lock_is_renewed_and_a_lost_lock_is_noticed(s3, monkeypatch):
    import json

    monkeypatch.setattr(S3Lease, "LEASE_S", 0.6)
    store, path = "s3://sbrdf-test/lock3", f"sbrdf-test/lock3/{HOLDER_FILE}"
    with StoreLock(store, False) as lk:
        first = json.loads(s3.cat(path))["expires"]
        time.sleep(0.9)
        s3.invalidate_cache()
        assert json.loads(s3.cat(path))["expires"] > first  # renewed
        s3.pipe(path, json.dumps({"pid": 1, "host": "elsewhere", "expires": time.time() + 999}).encode())
        time.sleep(0.5)
        assert lk.lock.lost
    assert json.loads(s3.cat(path))["host"] == "elsewhere"  # not removed: not ours any more
    s3.rm(path)


# -- a graph on S3 with a LocalCluster ------------------------------------------------------


def test_a_graph_runs_on_s3_with_a_local_cluster_like_on_a_local_store(s3, cluster, local_arrays, capsys):
    from sbrdf_core.cli import main

    store = "s3://sbrdf-test/run1"
    report = run_graph(graph_text(store), scheduler=cluster.scheduler.address, progress=False)
    assert [r.status for r in report.nodes] == ["computed"] * 3
    assert_same(arrays_of(store), local_arrays)
    assert not s3.exists(f"sbrdf-test/run1/{HOLDER_FILE}")
    again = run_graph(graph_text(store), scheduler=cluster.scheduler.address, progress=False)
    assert [r.status for r in again.nodes] == ["cached"] * 3
    # sbrdf verify on the S3 store: sound, then a damaged chunk found and repaired
    assert main(["verify", store]) == 0
    chunk = sorted(p for p in s3.find("sbrdf-test/run1/fit/params") if "/c/" in p)[0]
    data = bytearray(s3.cat(chunk))
    data[len(data) // 2] ^= 0xFF
    s3.pipe(chunk, bytes(data))
    capsys.readouterr()
    assert main(["verify", store]) == 1
    assert "DAMAGED" in capsys.readouterr().out
    assert main(["verify", "--repair", store]) == 1
    fixed = run_graph(graph_text(store), scheduler=cluster.scheduler.address, progress=False)
    assert fixed["fit"].status == "resumed" and fixed["fit"].chunks_written == 1
    assert main(["verify", store]) == 0
    assert_same(arrays_of(store), local_arrays)


RUNNER = """
import sys
from sbrdf_core.runner import run_graph
run_graph(sys.stdin.read(), scheduler=sys.argv[1], progress=False)
"""


def test_a_run_on_s3_killed_mid_way_resumes_without_recomputing(s3, cluster, local_arrays):
    store = "s3://sbrdf-test/run2"
    proc = subprocess.Popen([sys.executable, "-c", RUNNER, cluster.scheduler.address], stdin=subprocess.PIPE,
                            env=os.environ.copy())
    proc.stdin.write(graph_text(store).encode())
    proc.stdin.close()
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # the first done marker of the Fit node: the first node is complete
        s3.invalidate_cache()
        if s3.exists("sbrdf-test/run2/fit/_done") and s3.find("sbrdf-test/run2/fit/_done"):
            if any("/c/" in p for p in s3.find("sbrdf-test/run2/fit/_done")):
                break
        assert proc.poll() is None, "the run finished before it could be killed"
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert s3.exists(f"sbrdf-test/run2/{HOLDER_FILE}")  # a killed run leaves its lock behind
    time.sleep(1.0)  # let the cluster finish the killed run's tasks already running
    report = run_graph(graph_text(store), scheduler=cluster.scheduler.address, progress=False)
    a, fit = report["a"], report["fit"]
    assert a.status == "cached"
    assert fit.status == "resumed" and fit.chunks_resumed >= 1
    assert fit.chunks_written + fit.chunks_resumed == fit.chunks_total
    assert_same(arrays_of(store), local_arrays)


def test_a_store_on_a_non_lockable_file_system_warns(caplog):
    with caplog.at_level("WARNING", logger="sbrdf_core.store"):
        with StoreLock("memory://unlocked-store"):
            pass
    assert "is not locked" in caplog.text

