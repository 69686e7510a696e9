"""Direct chunk-file reads (sbrdf_core.store._shards) return exactly what zarr returns, or leave the read to zarr."""

from __future__ import annotations

import os
import tempfile

import numpy as np
import pytest
import zarr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sbrdf_core.store import CheckedArray, ChunkError
from sbrdf_core.store._artifact import _codecs
from sbrdf_core.store._shards import read_direct


def _array(root: str, shape, chunks, dtype, shards=None, seed=0) -> zarr.Array:
    """An array as the project writes them (blosc lz4 + crc32c, every chunk written), filled at random."""
    with zarr.config.set({"array.write_empty_chunks": True}):
        z = zarr.create_array(store=root, shape=shape, chunks=chunks, shards=shards, dtype=dtype,
                              fill_value=0, compressors=_codecs())
    rng = np.random.default_rng(seed)
    data = rng.normal(size=shape) if np.dtype(dtype).kind == "f" else rng.integers(0, 2 if dtype == "bool" else 200, shape)
    if np.dtype(dtype).kind == "f" and data.size:
        data.flat[::7] = np.nan  # NaN must come back as NaN
    z[...] = data.astype(dtype)
    return zarr.open_array(store=root, mode="r")


@st.composite
def layouts(draw):
    ndim = draw(st.integers(1, 4))
    shape = tuple(draw(st.integers(1, 9)) for _ in range(ndim))
    chunks = tuple(draw(st.integers(1, n)) for n in shape)
    shards = None
    if draw(st.booleans()):
        shards = tuple(c * draw(st.integers(1, 3)) for c in chunks)
    dtype = draw(st.sampled_from(["float32", "float64", "bool", "uint8", "int64"]))
    return shape, chunks, shards, dtype


@st.composite
def aligned(draw, shape, chunks):
    """A chunk-aligned selection: slices on chunk boundaries (or the end), some axes an int, maybe an Ellipsis."""
    sel = []
    for n, c in zip(shape, chunks):
        edges = list(range(0, n, c)) + [n]
        if c == 1 and draw(st.booleans()):
            sel.append(draw(st.integers(-n, n - 1)))
            continue
        a = draw(st.integers(0, len(edges) - 2))
        b = draw(st.integers(a + 1, len(edges) - 1))
        sel.append(slice(edges[a], edges[b]))
    if draw(st.booleans()) and len(sel) > 1:
        cut = draw(st.integers(1, len(sel)))
        if all(s == slice(0, n) for s, n in zip(sel[cut:], shape[cut:])):
            return tuple(sel[:cut]) + (Ellipsis,)
    return tuple(sel)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), layout=layouts())
def test_aligned_reads_equal_zarr(data, layout):
    shape, chunks, shards, dtype = layout
    with tempfile.TemporaryDirectory() as tmp:
        z = _array(tmp, shape, chunks, dtype, shards)
        inner = z.chunks  # the unit read (a shard's inner chunk when sharded)
        sel = data.draw(aligned(shape, inner))
        got = read_direct(z, sel)
        want = z[sel]
        assert got is not None, f"aligned selection {sel} of {shape} in {inner} chunks was left to zarr"
        assert got.shape == np.shape(want) and got.dtype == want.dtype
        assert np.array_equal(got, want, equal_nan=got.dtype.kind == "f")


def test_the_stack_layout_tile_read(tmp_path):
    """Reflectance's read: one texel tile of every pose-block shard (the last one part-filled)."""
    z = _array(str(tmp_path), (37, 16, 16, 3), (8, 4, 4, 3), "float32", shards=(8, 16, 16, 3))
    sel = (slice(None), slice(4, 8), slice(12, 16))
    assert np.array_equal(read_direct(z, sel), z[sel], equal_nan=True)
    assert np.array_equal(read_direct(z, slice(32, 37)), z[32:37], equal_nan=True)
    assert read_direct(z, 36) is None  # one pose of an 8-pose chunk: not a whole chunk


@pytest.mark.parametrize("sel", [(slice(1, 4),), (slice(0, 3, 2),), ([0, 1],), (np.array([0]),), (slice(0, 0),)])
def test_unaligned_or_fancy_selections_are_left_to_zarr(tmp_path, sel):
    z = _array(str(tmp_path), (8, 4), (4, 4), "float32")
    assert read_direct(z, sel) is None


@pytest.mark.parametrize("sharded", [False, True])
def test_a_damaged_chunk_is_left_to_zarr_which_names_it(tmp_path, sharded):
    z = _array(str(tmp_path / "a"), (8, 4), (4, 4), "float32", shards=(8, 4) if sharded else None)
    path = tmp_path / "a" / "c" / "0" / "0"
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 3] ^= 0xFF  # inside the first chunk's compressed bytes (or its shard's)
    path.write_bytes(bytes(raw))
    assert read_direct(z, (slice(0, 4),)) is None
    with pytest.raises(ChunkError, match="checksum"):
        CheckedArray(z, str(tmp_path / "a"), "a")[0:4]


def test_a_missing_or_truncated_chunk_file_reads_as_zarr_reads_it(tmp_path):
    z = _array(str(tmp_path / "a"), (8, 4), (4, 4), "float32")
    os.remove(tmp_path / "a" / "c" / "1" / "0")
    assert read_direct(z, (slice(4, 8),)) is None
    assert np.array_equal(CheckedArray(z, "a", "a")[4:8], np.zeros((4, 4), np.float32))  # zarr's fill value
    s = _array(str(tmp_path / "s"), (8, 4), (4, 4), "float32", shards=(8, 4))
    shard = tmp_path / "s" / "c" / "0" / "0"
    shard.write_bytes(shard.read_bytes()[:10])
    assert read_direct(s, (slice(0, 4),)) is None


def test_other_stores_are_left_to_zarr():
    z = zarr.create_array(store=zarr.storage.MemoryStore(), shape=(4,), chunks=(2,), dtype="float32",
                          compressors=_codecs())
    z[...] = 1.0
    assert read_direct(z, (slice(0, 2),)) is None


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(layout=layouts(), seed=st.integers(0, 2**16), zeros=st.booleans())
def test_direct_writes_are_zarrs_bytes(layout, seed, zeros):
    """Every chunk or shard written by write_direct is the file zarr writes for it (edge chunks and shards
    padded with the fill value; a shard's inner chunks in zarr's order, then its index), all-fill ones too."""
    from sbrdf_core.store._shards import write_direct

    shape, chunks, shards, dtype = layout
    with tempfile.TemporaryDirectory() as tmp:
        want = _array(os.path.join(tmp, "zarr"), shape, chunks, dtype, shards=shards, seed=seed)
        if zeros:  # fill-valued chunks: zarr still writes them (write_empty_chunks), so must write_direct
            with zarr.config.set({"array.write_empty_chunks": True}):
                zarr.open_array(store=os.path.join(tmp, "zarr"), mode="r+")[...] = 0
            want = zarr.open_array(store=os.path.join(tmp, "zarr"), mode="r")
        with zarr.config.set({"array.write_empty_chunks": True}):
            z = zarr.create_array(store=os.path.join(tmp, "direct"), shape=shape, chunks=chunks, shards=shards,
                                  dtype=dtype, fill_value=0, compressors=_codecs())
        values = want[...]
        unit = shards or chunks
        grid = tuple(-(-n // c) for n, c in zip(shape, unit))
        for index in np.ndindex(*grid):
            region = tuple(slice(i * c, min((i + 1) * c, n)) for i, c, n in zip(index, unit, shape))
            assert write_direct(z, region, values[region])
        for index in np.ndindex(*grid):
            rel = os.path.join("c", *map(str, index))
            with open(os.path.join(tmp, "zarr", rel), "rb") as a, open(os.path.join(tmp, "direct", rel), "rb") as b:
                assert a.read() == b.read(), rel
        assert not [f for _, _, fs in os.walk(tmp) for f in fs if f.endswith(".partial")]
        np.testing.assert_array_equal(zarr.open_array(store=os.path.join(tmp, "direct"), mode="r")[...], values)


def test_writes_zarr_must_make_are_refused(tmp_path):
    from sbrdf_core.store._shards import write_direct

    s = _array(str(tmp_path / "s"), (8, 4), (4, 4), "float32", shards=(8, 4))
    shard = (tmp_path / "s" / "c" / "0" / "0").read_bytes()
    assert not write_direct(s, (slice(0, 4), slice(0, 4)), np.zeros((4, 4), np.float32))  # one chunk of a shard
    assert (tmp_path / "s" / "c" / "0" / "0").read_bytes() == shard
    z = _array(str(tmp_path / "z"), (8, 4), (4, 4), "float32")
    before = (tmp_path / "z" / "c" / "0" / "0").read_bytes()
    assert not write_direct(z, (slice(0, 2), slice(0, 4)), np.zeros((2, 4), np.float32))  # part of a chunk
    assert not write_direct(z, (slice(0, 4), slice(0, 4)), np.zeros((2, 4), np.float32))  # the wrong shape
    assert (tmp_path / "z" / "c" / "0" / "0").read_bytes() == before
    plain = zarr.open_array(store=str(tmp_path / "z"), mode="r+")  # without write_empty_chunks: zarr skips fill
    assert not write_direct(plain, (slice(0, 4), slice(0, 4)), np.zeros((4, 4), np.float32))
    assert (tmp_path / "z" / "c" / "0" / "0").read_bytes() == before


def test_zero_dimensional_arrays_are_left_to_zarr(tmp_path):
    from sbrdf_core.store._shards import write_direct

    z = _array(str(tmp_path / "z"), (), (), "float32")
    assert read_direct(z, ()) is None
    assert not write_direct(z, (), np.float32(1.0))
    assert not (tmp_path / "z" / "c").is_dir()
