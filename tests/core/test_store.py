"""Artifacts in zarr: markers, completion, chunking policies."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from sbrdf_core.artifacts import ParamMaps
from sbrdf_core.errors import ArtifactError
from sbrdf_core.store import MARKERS, ArrayLayout, ArtifactWriter, open_artifact, texel_tile, write_chunk


def test_never_complete_until_every_chunk_is_written(tmp_path):
    url = str(tmp_path / "a")
    lay = {"rms": ArrayLayout((4, 6), (2, 3), "float32", float("nan"))}
    w = ArtifactWriter(url, ParamMaps, "tok")
    assert w.state() == "missing"
    assert w.prepare(lay, {}) == {"rms": set()}
    write_chunk(np.zeros((2, 3)), url, "rms", "tok", (0, 0), (slice(0, 2), slice(0, 3)))  # equals fill? no: 0 != nan
    write_chunk(np.full((2, 3), np.nan), url, "rms", "tok", (1, 1), (slice(2, 4), slice(3, 6)))  # equals fill value
    assert w.done("rms") == {"0.0", "1.1"}
    with pytest.raises(ArtifactError, match="2 chunks of 'rms' were not written"):
        w.mark_complete(lay, {})
    assert w.state() == "partial"
    with pytest.raises(ArtifactError, match="incomplete"):
        open_artifact(url)
    # resume keeps what was written
    assert ArtifactWriter(url, ParamMaps, "tok").prepare(lay, {}) == {"rms": {"0.0", "1.1"}}
    for idx in ((0, 1), (1, 0)):
        write_chunk(np.ones((2, 3)), url, "rms", "tok", idx, tuple(slice(i * c, (i + 1) * c) for i, c in zip(idx, (2, 3))))
    w.mark_complete(lay, {"summary": 1})
    art = open_artifact(url, kind=ParamMaps)
    assert art.complete and art.names() == ["rms"] and art.attrs["summary"] == 1
    # a different token (changed parameters) starts over
    assert ArtifactWriter(url, ParamMaps, "other").state() == "stale"


def test_a_killed_writers_temporary_marker_file_is_not_a_chunk(tmp_path):
    """zarr writes ``<key>.<uuid>.partial`` and renames it; SIGKILL between the two
    leaves the temporary file, which once counted as a ninth chunk of eight."""
    url = str(tmp_path / "a")
    lay = {"rms": ArrayLayout((4,), (2,), "float32")}
    w = ArtifactWriter(url, ParamMaps, "t")
    w.prepare(lay, {})
    write_chunk(np.ones(2), url, "rms", "t", (0,), (slice(0, 2),))
    markers = tmp_path / "a" / MARKERS / "rms" / "c"
    assert (markers / "0").exists()
    (markers / "1.0123456789abcdef.partial").write_bytes(b"\x01")
    assert w.done("rms") == {"0"}
    assert ArtifactWriter(url, ParamMaps, "t").prepare(lay, {}) == {"rms": {"0"}}
    assert not list((tmp_path / "a").rglob("*.partial")), "resuming leaves no temporary file behind"
    with pytest.raises(ArtifactError, match="1 chunks of 'rms' were not written"):
        w.mark_complete(lay, {})
    write_chunk(np.ones(2), url, "rms", "t", (1,), (slice(2, 4),))
    w.mark_complete(lay, {})
    assert open_artifact(url).complete


def test_chunk_shape_mismatch_is_refused(tmp_path):
    url = str(tmp_path / "a")
    ArtifactWriter(url, ParamMaps, "t").prepare({"rms": ArrayLayout((4,), (2,), "float32")}, {})
    with pytest.raises(ArtifactError, match="shape"):
        write_chunk(np.zeros(3), url, "rms", "t", (0,), (slice(0, 2),))


def test_wrong_kind_is_refused(tmp_path):
    url = str(tmp_path / "a")
    w = ArtifactWriter(url, ParamMaps, "t")
    w.prepare({}, {})
    w.mark_complete({}, {})
    with pytest.raises(ArtifactError, match="holds a ParamMaps, expected CaptureSet"):
        open_artifact(url, kind="CaptureSet")
    with pytest.raises(ArtifactError, match="no artifact"):
        open_artifact(str(tmp_path / "nothing"))


@pytest.mark.parametrize("poses, expected", [(10, 128), (200, 64), (1024, 32), (1025, 16), (2000, 16), (4097, 8), (8000, 8)])
def test_texel_tile_keeps_all_poses_of_a_tile_in_one_chunk(poses, expected):
    assert texel_tile((512, 512), poses, channels=4) == expected
    assert texel_tile((20, 24), poses) <= 24
    # the chunk, and a worker's memory for it, stays bounded however many poses
    assert expected**2 * poses * 4 * 4 <= 16 * 2**20


def test_a_strided_block_is_written_without_a_copy_of_it(tmp_path):
    """Register writes radiance as a view of its packed (k, V, U, 4) block, Reflectance f_r
    of its tile: a whole contiguous copy (and the crc's bytes of it) cost the block's size
    again in every writing thread.  The values, shards and crc are those of the copy."""
    import tracemalloc

    import zarr

    from sbrdf_core.store import chunk_crc

    url = str(tmp_path / "a")
    k, V, U = 16, 128, 128
    lay = {"radiance": ArrayLayout((2 * k, V, U, 3), (k, V, U, 3), "float32", float("nan"), inner=(k, 16, 16, 3))}
    ArtifactWriter(url, ParamMaps, "t").prepare(lay, {})
    packed = np.zeros((k, V, U, 4), np.float32)  # zeros: zarr's own encoded buffers stay small
    view = packed[..., :3]
    region = (slice(0, k), slice(0, V), slice(0, U), slice(0, 3))
    write_chunk(view, url, "radiance", "t", (0, 0, 0, 0), region)  # arrays opened and cached
    tracemalloc.start()
    try:
        write_chunk(view, url, "radiance", "t", (0, 0, 0, 0), region)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < view.nbytes / 2, f"{peak} bytes traced writing a {view.nbytes}-byte block"
    packed[..., :3] = np.random.default_rng(0).random((k, V, U, 3), dtype=np.float32)
    write_chunk(view, url, "radiance", "t", (1, 0, 0, 0), (slice(k, 2 * k),) + region[1:])
    z = zarr.open_group(url, mode="r")
    np.testing.assert_array_equal(z["radiance"][k:], view)
    crc = int(z[f"{MARKERS}/radiance"][1, 0, 0, 0])
    import google_crc32c

    assert crc == chunk_crc(view) == int(google_crc32c.value(np.ascontiguousarray(view).tobytes()))


# -- a partial artifact always resumes ---------------------------------------------------------------


def _killed_during_creation(url, lay, keep: int):
    """The artifact a run killed in ``prepare`` leaves: group and marker file written, only the first
    ``keep`` of the arrays and marker arrays created (in creation order: data, markers, data, ...)."""
    import shutil
    from pathlib import Path

    ArtifactWriter(url, ParamMaps, "t").prepare(lay, {})
    created = [p for name in lay for p in (name, f"{MARKERS}/{name.replace('/', '.')}")]
    for rel in created[keep:]:
        shutil.rmtree(Path(url) / rel)


@pytest.mark.parametrize("keep", [0, 1, 2, 3])
def test_an_artifact_killed_between_array_creations_resumes(tmp_path, keep):
    """A kill after the marker file, between two ``create_array`` calls, left arrays without a
    ``zarr.json``; every later run then failed with FileNotFoundError."""
    url = str(tmp_path / "s" / "a")
    lay = {"rms": ArrayLayout((4,), (2,), "float32"), "params/rho_d": ArrayLayout((2, 3), (1, 3), "float32")}
    _killed_during_creation(url, lay, keep)
    w = ArtifactWriter(url, ParamMaps, "t")
    assert w.state() == "partial"
    assert w.prepare(lay, {}) == {"rms": set(), "params/rho_d": set()}
    for i in (0, 1):
        write_chunk(np.full(2, i + 1.0), url, "rms", "t", (i,), (slice(2 * i, 2 * i + 2),))
        write_chunk(np.full((1, 3), i), url, "params/rho_d", "t", (i, 0), (slice(i, i + 1), slice(0, 3)))
    w.mark_complete(lay, {})
    art = open_artifact(url)
    assert art.read("rms").tolist() == [1, 1, 2, 2] and art.read("params/rho_d").tolist() == [[0] * 3, [1] * 3]


def test_a_partial_artifacts_bad_metadata_or_a_directory_where_a_chunk_goes_is_fixed_on_resume(tmp_path):
    import json
    from pathlib import Path

    url = str(tmp_path / "s" / "a")
    lay = {"rms": ArrayLayout((4,), (2,), "float32"), "n": ArrayLayout((4,), (2,), "int32")}
    w = ArtifactWriter(url, ParamMaps, "t")
    w.prepare(lay, {})
    write_chunk(np.ones(2), url, "rms", "t", (0,), (slice(0, 2),))
    write_chunk(np.ones(2), url, "n", "t", (0,), (slice(0, 2),))
    meta = Path(url) / "n" / "zarr.json"
    meta.write_text(json.dumps({**json.loads(meta.read_text()), "data_type": "float64"}))
    (Path(url) / "rms" / "c" / "1").mkdir(parents=True)  # where chunk 1 is written
    (Path(url) / "rms" / "c" / "1" / "x").write_text("x")
    from sbrdf_core.store import _artifact as store_module

    store_module._ARRAYS.clear()
    done = ArtifactWriter(url, ParamMaps, "t").prepare(lay, {})
    assert done == {"rms": {"0"}, "n": set()}  # n created again: its chunks are rewritten
    write_chunk(np.full(2, 2.0), url, "rms", "t", (1,), (slice(2, 4),))
    for i in (0, 1):
        write_chunk(np.full(2, 3), url, "n", "t", (i,), (slice(2 * i, 2 * i + 2),))
    w.mark_complete(lay, {})
    assert open_artifact(url).read("rms").tolist() == [1, 1, 2, 2]
    assert open_artifact(url).read("n").dtype == np.int32


def test_a_run_killed_while_removing_an_artifact_leaves_nothing_half_deleted(tmp_path, monkeypatch):
    """The old artifact is renamed aside before it is deleted: a kill during the delete leaves a hidden
    trash directory, removed by the next prepare, never a half-deleted artifact without its marker."""
    from pathlib import Path

    url = str(tmp_path / "s" / "a")
    lay = {"rms": ArrayLayout((4,), (2,), "float32")}
    ArtifactWriter(url, ParamMaps, "t").prepare(lay, {})
    import shutil

    def killed(path, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(shutil, "rmtree", killed)
    with pytest.raises(KeyboardInterrupt):
        ArtifactWriter(url, ParamMaps, "u").prepare(lay, {})
    monkeypatch.undo()
    assert not Path(url).exists() and [p.name[:13] for p in (tmp_path / "s").iterdir()] == [".sbrdf-trash-"]
    assert ArtifactWriter(url, ParamMaps, "u").prepare(lay, {}) == {"rms": set()}
    assert [p.name for p in (tmp_path / "s").iterdir()] == ["a"]


def test_the_store_package_exports_each_public_name_from_its_module():
    """``sbrdf_core.store`` loads its private modules on first use: every name in ``__all__`` resolves, and
    the names a graph's validation needs come without zarr (checked in a fresh process)."""
    import subprocess
    import sys

    import sbrdf_core.store as store

    assert sorted(store._WHERE) == store.__all__
    for name in store.__all__:
        assert getattr(store, name) is getattr(importlib.import_module(f"sbrdf_core.store.{store._WHERE[name]}"), name)
    code = ("import sys; from sbrdf_core.store import ARTIFACT_MARKER, NODE_NAME, join, texel_tile; "
            "print([m for m in ('zarr', 'fsspec') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
