"""A store no graph can escape or corrupt silently (issue 21): node names, path
confinement, chunk checksums, the reuse check, ``sbrdf verify``, the store lock.

Each damage test starts from a copy of one finished store and compares the
repaired store with the undamaged one.  On the code before issue 21 each of
them fails: bad node names validated, a damaged artifact was reported
``cached`` (or read back as other numbers), and there was no lock.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zarr

from sbrdf_core.cli import main as cli
from sbrdf_core.errors import ArtifactError, GraphError, RunError
from sbrdf_core.graph import load_graph
from sbrdf_core.runner import Runner
from sbrdf_core.store import ArtifactWriter, StoreBusy, StoreLock, check_artifact, inside_store, open_artifact

from ..conftest import assert_stores_equal, graph_yaml

CHANGED_FIT = {"model": "lambert", "iterations": 7}


@pytest.fixture(scope="module")
def finished(tmp_path_factory, registry) -> Path:
    """One finished six-node store, never modified (tests damage copies)."""
    root = tmp_path_factory.mktemp("finished")
    g = root / "g.yaml"
    g.write_text(graph_yaml(root / "s"))
    Runner(registry).run(load_graph(g, registry))
    return root / "s"


@pytest.fixture
def store(finished, tmp_path, write_graph, registry):
    """A copy of the finished store, and ``run(**graph_changes)`` on it."""
    s = tmp_path / "s"
    shutil.copytree(finished, s)

    def run(fit=None, **kw):
        return Runner(registry, **kw).run(load_graph(write_graph(graph_yaml(s, fit=fit)), registry))

    return s, run


def chunk(store: Path, array: str) -> Path:
    """The first chunk file of an array."""
    return sorted(p for p in (store / array / "c").rglob("*") if p.is_file())[0]


# -- node names and confinement ------------------------------------------------------------------


@pytest.mark.parametrize("name", ["../../victim", ".", "", "a/b", "..", "x" * 65, "-lead"])
def test_node_names_are_identifiers_checked_with_their_line(write_graph, registry, tmp_path, name):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "zarr.json").write_text("{}")
    (victim / "beside.txt").write_text("precious")
    text = graph_yaml(tmp_path / "a" / "b" / "s").replace("  render: {kind", f"  {json.dumps(name)}: {{kind")
    with pytest.raises(GraphError) as e:
        load_graph(write_graph(text), registry)
    assert f"graph.yaml:9: node name {name!r} is not an identifier" in str(e.value)
    assert (victim / "beside.txt").read_text() == "precious"


def test_every_written_or_deleted_path_is_proven_inside_the_store(tmp_path, registry, write_graph):
    store = tmp_path / "s"
    store.mkdir()
    (tmp_path / "outside").mkdir()
    (store / "link").symlink_to(tmp_path / "outside")
    for bad in (str(store), str(store) + "/.", str(store) + "/../victim", str(store / "link" / "x"), str(tmp_path)):
        with pytest.raises(ArtifactError, match="outside the store"):
            inside_store(str(store), bad)
    assert inside_store(str(store), str(store / "fit")) == str(store / "fit")
    with pytest.raises(ArtifactError, match="outside the store"):
        inside_store("memory://b/s", "memory://b/s/../t")
    # a graph built by hand (no validation) still cannot write outside: the runner checks again
    g = load_graph(write_graph(graph_yaml(store)), registry)
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "zarr.json").write_text('{"zarr_format": 3, "node_type": "group", "attributes": {}}')
    node = g.nodes.pop("capture")
    node.name = "../victim"
    g.nodes = {"../victim": node}
    with pytest.raises(ArtifactError, match="outside the store"):
        Runner(registry).run(g)
    assert (victim / "zarr.json").exists()


def test_only_this_nodes_marked_artifact_is_ever_removed(tmp_path):
    from sbrdf_core.artifacts import ParamMaps
    from sbrdf_core.store import ArrayLayout

    store = tmp_path / "s"
    foreign = store / "fit"
    foreign.mkdir(parents=True)
    (foreign / "zarr.json").write_text('{"zarr_format": 3, "node_type": "group", "attributes": {}}')
    (foreign / "data.txt").write_text("not ours")
    w = ArtifactWriter(str(foreign), ParamMaps, "t", store=str(store), node="fit")
    assert w.state() == "stale"
    with pytest.raises(ArtifactError, match="not the artifact of node 'fit'.*refusing to delete"):
        w.prepare({"rms": ArrayLayout((2,), (2,), "float32")}, {})
    assert (foreign / "data.txt").read_text() == "not ours"
    # our own artifact (its marker names the node) is replaced when its token changes
    own = ArtifactWriter(str(store / "own"), ParamMaps, "t", store=str(store), node="own")
    own.prepare({"rms": ArrayLayout((2,), (2,), "float32")}, {})
    assert ArtifactWriter(str(store / "own"), ParamMaps, "u", store=str(store), node="own").state() == "stale"
    ArtifactWriter(str(store / "own"), ParamMaps, "u", store=str(store), node="own").prepare({}, {})
    # ... but another node's artifact is not (a node renamed onto it)
    with pytest.raises(ArtifactError, match="not the artifact of node 'other'"):
        ArtifactWriter(str(store / "own"), ParamMaps, "v", store=str(store), node="other").prepare({}, {})


# -- damage: found on reuse, at read time, by verify ---------------------------------------------------


def test_every_array_is_written_with_a_crc32c_checksum(finished):
    meta = json.loads((finished / "fit" / "params" / "rho_d" / "zarr.json").read_text())
    assert [c["name"] for c in meta["codecs"]][-1] == "crc32c"
    assert not check_artifact(str(finished / "fit"), full=True)


@pytest.mark.parametrize("array", ["fit/params/rho_d", "reflectance/f_r"])
def test_a_deleted_chunk_is_recomputed_on_reuse(store, finished, array):
    s, run = store
    chunk(s, array).unlink()
    node = array.split("/")[0]
    rep = run()
    assert rep[node].status == "resumed" and rep[node].chunks_written == 1
    assert "lost" in rep[node].notes[0] and array.split("/", 1)[1] in rep[node].notes[0]
    assert all(r.status == "cached" for r in rep.nodes if r.node != node)  # same token: downstream still valid
    assert_stores_equal(s, finished)


def test_a_bit_flip_fails_the_read_naming_artifact_array_and_chunk(store, finished):
    s, run = store
    c = chunk(s, "reflectance/f_r")
    data = bytearray(c.read_bytes())
    data[len(data) // 2] ^= 0x10
    c.write_bytes(bytes(data))
    key = ".".join(c.relative_to(s / "reflectance" / "f_r" / "c").parts)
    with pytest.raises(RunError, match=rf"node 'fit': damaged artifact .*reflectance: array 'f_r', chunk {key}: "
                                       r"crc32c checksum mismatch.*re-run"):
        run(fit=CHANGED_FIT)  # fit must read the samples again
    rep = run(fit=CHANGED_FIT)
    assert rep["reflectance"].status == "resumed" and rep["reflectance"].chunks_written == 1
    rep = run()
    assert_stores_equal(s, finished)


def test_an_edited_shape_in_zarr_json_recomputes_the_artifact(store, finished):
    s, run = store
    meta_path = s / "fit" / "params" / "rho_d" / "zarr.json"
    meta = json.loads(meta_path.read_text())
    meta["shape"] = [64, 64, 3]
    meta_path.write_text(json.dumps(meta))
    rep = run()
    assert rep["fit"].status == "computed" and "shape" in rep["fit"].notes[0]
    assert rep["quantize"].status == "cached"
    assert open_artifact(str(s / "fit")).read("params/rho_d").shape == (20, 24, 3)
    assert_stores_equal(s, finished)


def test_random_bytes_in_a_chunk_are_reported_by_verify_and_repaired(store, finished, capsys):
    s, run = store
    c = chunk(s, "quantize/error")
    c.write_bytes(os.urandom(c.stat().st_size))
    assert run()["quantize"].status == "cached"  # the reuse check reads no chunk
    assert cli(["verify", str(s)]) == 1
    out = capsys.readouterr().out
    key = ".".join(c.relative_to(s / "quantize" / "error" / "c").parts)
    assert f"quantize  TextureSet  DAMAGED\n    array 'error', chunk {key}:" in out
    assert "sbrdf verify --repair" in out and "1 damaged" in out
    assert cli(["verify", "--repair", str(s)]) == 1
    assert "repaired: the next run recomputes 1 chunk of 'error' of node 'quantize'" in capsys.readouterr().out
    rep = run()
    assert rep["quantize"].status == "resumed" and rep["quantize"].chunks_written == 1
    assert cli(["verify", str(s)]) == 0
    assert_stores_equal(s, finished)


def test_a_deleted_side_file_is_written_again(store, finished):
    s, run = store
    (s / "render" / "image.png").unlink()
    rep = run()
    assert rep["render"].status == "resumed" and rep["render"].chunks_written == 0
    assert "image.png is missing" in rep["render"].notes[0]
    assert (s / "render" / "image.png").read_bytes() == (finished / "render" / "image.png").read_bytes()
    assert not check_artifact(str(s / "render"), full=True)


def test_a_deleted_group_zarr_json_recomputes_only_a_marked_artifact(store, finished):
    s, run = store
    (s / "quantize" / "zarr.json").unlink()
    rep = run()
    assert rep["quantize"].status == "computed" and "zarr.json" in rep["quantize"].notes[0]
    assert_stores_equal(s, finished)


def test_artifacts_written_without_checksums_still_read_and_verify(tmp_path):
    """Stores written before issue 21: no crc32c codec, no layout, no marker file."""
    url = str(tmp_path / "s" / "fit")
    g = zarr.open_group(url, mode="w", attributes={"kind": "ParamMaps", "version": 1, "token": "t", "complete": True,
                                                      "provenance": {"node": "fit"}})
    g.create_array("rms", shape=(4,), chunks=(2,), dtype="float32")[...] = [1, 2, 3, 4]
    assert open_artifact(url).read("rms").tolist() == [1, 2, 3, 4]
    assert not check_artifact(url) and not check_artifact(url, full=True)
    assert ArtifactWriter(url, None, "", store=str(tmp_path / "s"), node="fit").owned()


# -- two runs on one store ---------------------------------------------------------------------------


SLOW = {"poses": 30, "pose_delay_s": 0.1}


def test_a_second_run_in_another_thread_is_refused_naming_the_holder(tmp_path, write_graph, registry):
    g = load_graph(write_graph(graph_yaml(tmp_path / "s")), registry)
    errors = []
    with StoreLock(str(tmp_path / "s"), what="graph 'first'"):
        t = threading.Thread(target=lambda: errors.append(_catch(lambda: Runner(registry).run(g))))
        t0 = time.monotonic()
        t.start()
        t.join()
        assert time.monotonic() - t0 < 5
    assert isinstance(errors[0], StoreBusy)
    assert f"in use by pid {os.getpid()}" in str(errors[0]) and "graph 'first'" in str(errors[0]) and "--wait" in str(errors[0])
    assert not (tmp_path / "s" / "capture").exists()


def _catch(fn):
    try:
        fn()
    except Exception as e:
        return e


def test_a_second_process_refuses_clearly_or_waits(tmp_path, write_graph, registry):
    graph = write_graph(graph_yaml(tmp_path / "s", SLOW))
    cmd = [sys.executable, "-m", "sbrdf_core.cli", "run", "-q", str(graph)]
    first = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    holder = tmp_path / "s" / ".sbrdf.lock.json"
    deadline = time.monotonic() + 60
    while not holder.exists() and time.monotonic() < deadline:
        assert first.poll() is None, first.communicate()
        time.sleep(0.05)
    waiting = subprocess.Popen(cmd + ["--wait"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    refused = subprocess.run(cmd, capture_output=True, text=True)
    assert refused.returncode == 2 and time.monotonic() - t0 < 30
    assert f"is in use by pid {first.pid}" in refused.stderr and "Traceback" not in refused.stderr
    with pytest.raises(StoreBusy, match=f"pid {first.pid}"):
        Runner(registry).run(load_graph(graph, registry))
    out1, err1 = first.communicate(timeout=300)
    out2, err2 = waiting.communicate(timeout=300)
    assert first.returncode == 0, err1
    assert waiting.returncode == 0, err2
    assert "Traceback" not in err1 + err2 and "cached" in out2  # the waiting run found the first one's work
    assert all(open_artifact(str(tmp_path / "s" / n)).complete for n in ("capture", "fit", "render"))


def test_fill_valued_chunks_are_written_so_a_missing_file_means_a_lost_chunk(tmp_path):
    import numpy as np

    from sbrdf_core.artifacts import ParamMaps
    from sbrdf_core.store import ArrayLayout, write_chunk

    url = str(tmp_path / "s" / "a")
    lay = {"rms": ArrayLayout((4,), (2,), "float32", float("nan"))}
    w = ArtifactWriter(url, ParamMaps, "t")
    w.prepare(lay, {})
    for i in (0, 1):
        write_chunk(np.full(2, np.nan), url, "rms", "t", (i,), (slice(2 * i, 2 * i + 2),))
    w.mark_complete(lay, {})
    assert (tmp_path / "s" / "a" / "rms" / "c" / "1").exists()
    assert not check_artifact(url, full=True)
    (tmp_path / "s" / "a" / "rms" / "c" / "1").unlink()
    assert check_artifact(url).chunks == {"rms": {"1"}}


@pytest.mark.slow  # a dask.distributed cluster of worker processes
def test_a_damaged_chunk_read_on_a_cluster_is_named_too(store, cluster):
    _, client = cluster
    s, run = store
    c = chunk(s, "reflectance/f_r")
    c.write_bytes(c.read_bytes()[:-7])  # truncated
    with pytest.raises(RunError, match=r"reflectance: array 'f_r', chunk [0-9.]+: .*re-run"):
        run(fit=CHANGED_FIT, scheduler=client.scheduler.address)
    assert run(fit=CHANGED_FIT)["reflectance"].status == "resumed"


# -- nothing outside the store, every store repairable, verify tells the truth ------------------------


def snapshot(root: Path) -> dict:
    """Every entry below ``root`` (links as links) with its bytes: a sentinel that must not change."""
    out = {}
    for p in sorted(root.rglob("*")):
        out[str(p.relative_to(root))] = (f"-> {os.readlink(p)}" if p.is_symlink() else
                                         "dir" if p.is_dir() else p.read_bytes())
    return out


def verify(store: Path, *extra: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``sbrdf verify`` in a child process, so that a hang fails the test instead of stalling it."""
    return subprocess.run([sys.executable, "-m", "sbrdf_core.cli", "verify", *extra, str(store)],
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("what", ["chunk directory", "chunk file"])
def test_a_link_inside_an_artifact_is_never_followed_to_write_or_delete(store, finished, tmp_path, what):
    s, run = store
    outside = tmp_path / "outside"
    c = chunk(s, "reflectance/f_r")
    target = c.parent if what == "chunk directory" else c
    shutil.copytree(target, outside) if target.is_dir() else (outside.mkdir(), shutil.copy(target, outside / c.name))
    for f in outside.iterdir():  # damaged there: a repair would delete it, a run would rewrite it
        f.write_bytes(f.read_bytes()[:-3] + b"xyz")
    before = snapshot(outside)
    shutil.rmtree(target) if target.is_dir() else target.unlink()
    target.symlink_to(outside if target.is_dir() else outside / c.name)
    r = verify(s)
    assert r.returncode == 1 and "symbolic link" in r.stdout and "Traceback" not in r.stderr, r.stdout + r.stderr
    r = verify(s, "--repair")
    assert "repaired" in r.stdout and not target.is_symlink(), r.stdout + r.stderr
    assert snapshot(outside) == before
    rep = run()
    assert rep["reflectance"].status == "resumed"
    assert snapshot(outside) == before
    assert_stores_equal(s, finished)
    # and a run that finds the link itself (no verify first) removes it the same way
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(target) if target.is_dir() else target.unlink()
    target.symlink_to(outside if what == "chunk directory" else outside / c.name)
    rep = run()
    assert rep["reflectance"].status == "resumed" and "symbolic link" in rep["reflectance"].notes[0]
    assert snapshot(outside) == before and not target.is_symlink()
    assert_stores_equal(s, finished)


def test_damage_behind_complete_false_is_reported_and_repaired(store, finished):
    s, run = store
    zarr.open_group(str(s / "fit"), mode="r+").attrs["complete"] = False  # an interrupted run's artifact
    c = chunk(s, "fit/rms")
    data = bytearray(c.read_bytes())
    data[len(data) // 2] ^= 0x40
    c.write_bytes(bytes(data))  # a chunk counted as done: a resuming run would keep it
    r = verify(s)
    assert r.returncode == 1 and "fit  ParamMaps  DAMAGED (and incomplete" in r.stdout and "'rms'" in r.stdout, r.stdout
    assert verify(s, "--repair").returncode == 1
    rep = run()
    assert rep["fit"].status == "resumed"
    assert verify(s).returncode == 0
    assert_stores_equal(s, finished)


def test_a_chunk_file_replaced_by_a_directory_is_reported_and_rewritten(store, finished):
    s, run = store
    c = chunk(s, "register/valid")
    c.unlink()
    c.mkdir()
    (c / "x").write_text("x")
    r = verify(s)
    assert r.returncode == 1 and "register" in r.stdout and "lost" in r.stdout, r.stdout
    assert verify(s, "--repair").returncode == 1
    assert run()["register"].status == "resumed"
    assert verify(s).returncode == 0
    assert_stores_equal(s, finished)
    # a resuming run clears it too (an incomplete artifact, no verify)
    c.unlink()
    c.mkdir()
    zarr.open_group(str(s / "register"), mode="r+").attrs["complete"] = False
    assert run()["register"].status == "resumed"
    assert_stores_equal(s, finished)


def test_an_artifact_linked_to_another_store_is_reported_and_the_link_removed(store, finished, tmp_path):
    s, run = store
    other = tmp_path / "other"
    shutil.copytree(finished, other)
    before = snapshot(other)
    shutil.rmtree(s / "quantize")
    (s / "quantize").symlink_to(other / "quantize")
    r = verify(s)
    assert r.returncode == 1 and "quantize" in r.stdout and "symbolic link" in r.stdout, r.stdout
    with pytest.raises(ArtifactError):
        run()
    r = verify(s, "--repair")
    assert "the link was removed" in r.stdout and not (s / "quantize").exists(), r.stdout
    assert run()["quantize"].status == "computed"
    assert snapshot(other) == before
    assert verify(s).returncode == 0
    assert_stores_equal(s, finished)


def test_a_plain_file_where_an_artifact_goes_is_reported_never_deleted(store):
    s, run = store
    shutil.rmtree(s / "render")
    (s / "render").write_text("precious")
    r = verify(s)
    assert r.returncode == 1 and "plain file where node 'render'" in r.stdout and "move it away" in r.stdout, r.stdout
    assert verify(s, "--repair").returncode == 1
    assert (s / "render").read_text() == "precious"
    with pytest.raises(ArtifactError, match="not the artifact of node 'render'.*move it away"):
        run()
    assert (s / "render").read_text() == "precious"


def test_a_fifo_in_place_of_a_zarr_json_is_damage_not_a_hang(store, finished):
    s, run = store
    meta = s / "fit" / "params" / "rho_d" / "zarr.json"
    meta.unlink()
    os.mkfifo(meta)
    r = verify(s, timeout=60)
    assert r.returncode == 1 and "FIFO" in r.stdout, r.stdout + r.stderr
    assert verify(s, "--repair", timeout=60).returncode == 1
    assert run()["fit"].status == "computed"
    assert_stores_equal(s, finished)
    # a run that meets one (the quantize node's own artifact) does not hang either
    meta = s / "quantize" / "zarr.json"
    meta.unlink()
    os.mkfifo(meta)
    child = subprocess.run([sys.executable, "-m", "sbrdf_core.cli", "run", "-q", str(s.parent / "graph.yaml")],
                           capture_output=True, text=True, timeout=120)
    assert child.returncode == 0, child.stderr
    assert_stores_equal(s, finished)


def test_a_lock_file_that_is_a_link_is_refused_never_written_through(store, tmp_path):
    s, run = store
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (s / ".sbrdf.lock").unlink(missing_ok=True)
    (s / ".sbrdf.lock").symlink_to(victim)
    with pytest.raises(RunError, match=r"\.sbrdf\.lock is a symbolic link to .*victim\.txt.*refusing"):
        run()
    r = verify(s)
    assert r.returncode == 2 and "symbolic link" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert victim.read_text() == "precious" and (s / ".sbrdf.lock").is_symlink()


@pytest.mark.parametrize("lock_file", [True, False])
def test_verify_works_on_a_read_only_store(store, tmp_path, lock_file):
    s, _ = store
    (s / ".sbrdf.lock").unlink(missing_ok=True)
    if lock_file:
        (s / ".sbrdf.lock").write_bytes(b"")
    before = snapshot(s)
    mounted = None
    if os.geteuid() == 0:  # root writes through chmod: a read-only bind mount, where mounting is allowed
        ro = tmp_path / "ro"
        ro.mkdir()
        if subprocess.run(["mount", "--bind", "-o", "ro", str(s), str(ro)], capture_output=True).returncode:
            pytest.skip("running as root, and cannot mount a read-only bind mount here")
        mounted = ro
        subprocess.run(["mount", "-o", "remount,bind,ro", str(ro)], capture_output=True)
    else:
        subprocess.run(["chmod", "-R", "a-w", str(s)], check=True)
    target = mounted or s
    try:
        if os.access(target, os.W_OK):
            pytest.skip("the store stays writable here")
        r = verify(target)
        assert r.returncode == 0 and "verified read-only" in r.stdout and "0 damaged" in r.stdout, r.stdout + r.stderr
        assert ("under a shared lock" if lock_file else "without a lock") in r.stdout
        r = verify(target, "--repair")
        assert r.returncode == 2 and "Traceback" not in r.stderr and str(target) in r.stderr, r.stderr
    finally:
        if mounted:
            subprocess.run(["umount", str(mounted)], check=True)
        else:
            subprocess.run(["chmod", "-R", "u+w", str(s)], check=True)
    assert snapshot(s) == before


def test_info_on_an_edited_dtype_says_what_is_wrong(store, capsys):
    s, _ = store
    meta_path = s / "quantize" / "error" / "zarr.json"
    meta = json.loads(meta_path.read_text())
    meta["data_type"] = "not-a-dtype"
    meta_path.write_text(json.dumps(meta))
    assert cli(["info", str(s)]) == 0
    out = capsys.readouterr().out
    assert "error" in out and "metadata cannot be read" in out and "sbrdf verify" in out
    assert cli(["info", str(s / "quantize")]) == 0
    assert "Traceback" not in capsys.readouterr().err
    meta["data_type"] = "float64"
    meta_path.write_text(json.dumps(meta))
    assert cli(["info", str(s / "quantize")]) == 0
    assert "DAMAGED: its node declared shape (20, 24) float32" in capsys.readouterr().out


def test_a_full_disk_during_a_run_is_a_clear_error_and_the_run_resumes(store, finished, monkeypatch):
    import errno

    from sbrdf_core.store import _shards as chunk_files

    s, run = store
    shutil.rmtree(s / "fit")
    real = chunk_files._write_encoded
    calls = []

    def full(f, lay, data):
        calls.append(1)
        if len(calls) > 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(f, lay, data)

    monkeypatch.setattr(chunk_files, "_write_encoded", full)
    with pytest.raises(ArtifactError, match=rf"store {s}: no space left on the device writing artifact {s}/fit, "
                                            r"array '[a-z_/]+', chunk [0-9.]+\. Free space"):
        run()
    monkeypatch.undo()
    assert run()["fit"].status == "resumed"
    assert_stores_equal(s, finished)


@pytest.fixture
def small_filesystem(tmp_path):
    """A 6 MiB tmpfs (root only, where mounting is allowed)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=6m", "tmpfs", str(mnt)],
                                           capture_output=True).returncode:
        pytest.skip("cannot mount a small file system here")
    yield mnt
    subprocess.run(["umount", str(mnt)], check=True)


def test_a_really_full_disk_in_a_run_and_in_verify_repair_is_a_clear_error(small_filesystem, finished, write_graph):
    s = small_filesystem / "s"
    shutil.copytree(finished, s)
    chunk(s, "reflectance/f_r").write_bytes(b"garbage!")
    filler = small_filesystem / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
    try:  # fill the file system to the last byte
        while os.write(fd, b"\0" * 4096):
            pass
    except OSError:
        pass
    finally:
        os.close(fd)
    r = verify(s, "--repair")
    assert "Traceback" not in r.stderr and r.returncode in (1, 2), r.stderr
    assert "no space left" in r.stdout + r.stderr and str(s) in r.stdout + r.stderr, r.stdout + r.stderr
    graph = write_graph(graph_yaml(s, fit=CHANGED_FIT))
    child = subprocess.run([sys.executable, "-m", "sbrdf_core.cli", "run", "-q", str(graph)],
                           capture_output=True, text=True, timeout=300)
    assert child.returncode == 2 and "Traceback" not in child.stderr, child.stderr
    assert "no space left" in child.stderr and f"store {s}" in child.stderr, child.stderr
    filler.unlink()
    assert verify(s, "--repair").returncode == 1
    child = subprocess.run([sys.executable, "-m", "sbrdf_core.cli", "run", "-q", str(graph)],
                           capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stderr


@pytest.mark.parametrize("lost", [["params/rho_d", "_done/params.rho_d"], ["_done/rms"]])
def test_verify_tells_the_truth_about_a_store_killed_while_creating_arrays(store, finished, lost):
    """Arrays not created yet (a kill inside array creation) are what the resuming run creates: not
    damage; a marker array lost beside its data array is damage that repair and the run both fix."""
    s, run = store
    for rel in lost:
        shutil.rmtree(s / "fit" / rel)
    zarr.open_group(str(s / "fit"), mode="r+").attrs["complete"] = False
    r = verify(s)
    if len(lost) == 2:
        assert r.returncode == 0 and "fit  ParamMaps  incomplete" in r.stdout and "not created yet" in r.stdout, r.stdout
    else:
        assert r.returncode == 1 and "'rms': metadata missing" in r.stdout, r.stdout
        assert verify(s, "--repair").returncode == 1
    assert run()["fit"].status in ("resumed", "computed")
    assert verify(s).returncode == 0
    assert_stores_equal(s, finished)
