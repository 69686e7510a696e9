"""Chunk-aligned reads and whole-chunk writes of stored arrays, straight from and to their chunk files.

zarr-python reads one inner chunk of a shard with two opens of the shard file
(its index, then the chunk), a round trip through its event-loop thread and
several buffer copies, which cost many times the chunk's decoding.
Reflectance's transpose reads one inner chunk of every pose-block shard per
texel tile, so those per-chunk costs, not decoding, set the time of its reads
of the stack (docs/registration.md, "Reading the stack").

:func:`read_direct` reads a selection that starts and ends on chunk boundaries
of an array in a local store whose codecs are the ones this project writes
(``bytes`` → ``blosc`` → ``crc32c``, optionally inside ``sharding_indexed``
with its index at the end; zarr v3 spec): each shard file is opened once, its
index and the selected chunks are read with ``pread``, every crc32c is checked
and blosc decodes.  Anything else (another store, codec or key encoding, an
unaligned selection, a missing or damaged chunk) returns ``None``, and the
caller reads through zarr, whose answer (fill values, a checksum error) stands.
So this module decides only how fast a read is, never what it returns.
:func:`write_direct` is the same for :func:`sbrdf_core.store.write_chunk`'s
whole chunks, whole shards (Register's pose blocks) and done markers: zarr's
own file bytes, or ``False`` and zarr writes them.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

__all__ = ["read_direct", "write_direct"]

#: An empty inner chunk's (offset, nbytes) in a shard index (zarr v3 sharding spec).
_MISSING = 2**64 - 1


@dataclass(frozen=True)
class _Layout:
    root: str  # the array's folder
    separator: str  # of chunk keys: "c/0/1" or "c.0.1"
    shape: tuple[int, ...]
    chunk: tuple[int, ...]  # the chunk read as a unit (a shard's inner chunk when sharded)
    per_shard: tuple[int, ...] | None  # inner chunks per shard along each axis; None: not sharded
    dtype: np.dtype
    blosc: dict | None  # numcodecs Blosc's configuration, as zarr's codec makes it; None: no compressor
    fill_value: object


def _layout(z) -> _Layout | None:
    """The array's layout when :func:`read_direct` can read it, else ``None``."""
    from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec, ShardingCodec
    from zarr.codecs.sharding import ShardingCodecIndexLocation
    from zarr.core.chunk_key_encodings import DefaultChunkKeyEncoding
    from zarr.storage import LocalStore

    if not hasattr(os, "pread") or not isinstance(getattr(z, "store", None), LocalStore) or z.metadata is None:
        return None
    meta = z.metadata
    if meta.zarr_format != 3 or len(z.shape) == 0:  # a 0-d array's one chunk is the file "c": left to zarr
        return None
    if not isinstance(meta.chunk_key_encoding, DefaultChunkKeyEncoding):
        return None
    codecs, per_shard, chunk = tuple(meta.codecs), None, tuple(z.chunks)
    if len(codecs) == 1 and isinstance(codecs[0], ShardingCodec):
        sharding = codecs[0]
        index = tuple(sharding.index_codecs)
        if (sharding.index_location != ShardingCodecIndexLocation.end or len(index) != 2
                or not isinstance(index[0], BytesCodec) or not isinstance(index[1], Crc32cCodec)):
            return None
        shard, chunk = tuple(z.shards), tuple(sharding.chunk_shape)
        if any(s % c for s, c in zip(shard, chunk)):
            return None
        per_shard = tuple(s // c for s, c in zip(shard, chunk))
        codecs = tuple(sharding.codecs)
    kinds = [type(c) for c in codecs]
    if kinds not in ([BytesCodec, BloscCodec, Crc32cCodec], [BytesCodec, Crc32cCodec]):
        return None
    blosc = None
    if BloscCodec in kinds:
        b = codecs[1]
        blosc = {"cname": b.cname.name, "clevel": b.clevel, "blocksize": b.blocksize, "typesize": b.typesize,
                 "shuffle": {"noshuffle": 0, "shuffle": 1, "bitshuffle": 2}[b.shuffle.name]}
    dtype = np.dtype(z.dtype)
    if dtype.kind not in "biuf" or (dtype.itemsize > 1 and codecs[0].endian is not None
                                    and codecs[0].endian.value != "little"):
        return None
    root = os.path.join(str(z.store.root), z.store_path.path) if z.store_path.path else str(z.store.root)
    return _Layout(root, meta.chunk_key_encoding.separator, tuple(z.shape), chunk, per_shard,
                   dtype.newbyteorder("<"), blosc, meta.fill_value)


def _ranges(sel, shape: tuple[int, ...]) -> tuple[list[tuple[int, int]], list[int]] | None:
    """``sel`` as per-axis ``(start, stop)`` and the axes an integer removes; ``None`` if not plain slices and ints."""
    sel = sel if isinstance(sel, tuple) else (sel,)
    at = [i for i, s in enumerate(sel) if s is Ellipsis]
    if len(at) > 1:
        return None
    if at:
        sel = sel[:at[0]] + (slice(None),) * (len(shape) - len(sel) + 1) + sel[at[0] + 1:]
    if len(sel) > len(shape):
        return None
    sel = sel + (slice(None),) * (len(shape) - len(sel))
    out, squeeze = [], []
    for axis, (s, n) in enumerate(zip(sel, shape)):
        if isinstance(s, (int, np.integer)) and not isinstance(s, bool):
            i = int(s) + n if s < 0 else int(s)
            if not 0 <= i < n:
                return None
            out.append((i, i + 1))
            squeeze.append(axis)
        elif isinstance(s, slice) and s.step in (None, 1):
            lo, hi, _ = s.indices(n)
            out.append((lo, max(lo, hi)))
        else:
            return None
    return out, squeeze


def _crc32c(payload) -> bytes:
    """The ``crc32c`` codec's suffix of ``payload``: its checksum, 4 bytes little-endian (zarr v3 spec)."""
    import google_crc32c

    return google_crc32c.value(payload).to_bytes(4, "little")


def _crc_ok(data: bytes) -> bool:
    return len(data) >= 4 and _crc32c(data[:-4]) == data[-4:]


def read_direct(z, sel) -> np.ndarray | None:
    """``z[sel]`` read from the chunk files, or ``None`` where zarr must read it (see the module docstring)."""
    lay = _layout(z)
    if lay is None:
        return None
    parsed = _ranges(sel, lay.shape)
    if parsed is None:
        return None
    ranges, squeeze = parsed
    for (lo, hi), c, n in zip(ranges, lay.chunk, lay.shape):
        if hi <= lo or lo % c or (hi % c and hi != n):
            return None
    out = np.empty(tuple(hi - lo for lo, hi in ranges), lay.dtype)
    grid = [range(lo // c, -(-hi // c)) for (lo, hi), c in zip(ranges, lay.chunk)]
    # Chunks grouped by the file holding them: one open per shard (or chunk file).
    files: dict[tuple[int, ...], list[tuple[int, ...]]] = {}
    for index in np.ndindex(*(len(g) for g in grid)):
        ci = tuple(g[i] for g, i in zip(grid, index))
        key = tuple(c // p for c, p in zip(ci, lay.per_shard)) if lay.per_shard else ci
        files.setdefault(key, []).append(ci)
    for key, chunks in files.items():
        path = _path(lay, key)
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            return None
        try:
            if not _read_file(fd, lay, chunks, ranges, out):
                return None
        finally:
            os.close(fd)
    return out.reshape([n for axis, n in enumerate(out.shape) if axis not in squeeze]) if squeeze else out


def _path(lay: _Layout, key: tuple[int, ...]) -> str:
    """The file of chunk (or shard) ``key``: ``c/0/1`` (the default key encoding)."""
    return os.path.join(lay.root, "c" + lay.separator + lay.separator.join(map(str, key)))


def _read_file(fd: int, lay: _Layout, chunks: list[tuple[int, ...]], ranges, out: np.ndarray) -> bool:
    """Decode ``chunks`` of one open chunk or shard file into their places in ``out``; ``False`` on any anomaly."""
    from numcodecs import blosc

    if lay.per_shard is not None:
        n_inner = math.prod(lay.per_shard)
        size = os.fstat(fd).st_size
        raw = os.pread(fd, 16 * n_inner + 4, size - 16 * n_inner - 4) if size >= 16 * n_inner + 4 else b""
        if not _crc_ok(raw):
            return False
        index = np.frombuffer(raw, "<u8", count=2 * n_inner).reshape(n_inner, 2)
    nbytes_decoded = math.prod(lay.chunk) * lay.dtype.itemsize
    for ci in chunks:
        if lay.per_shard is None:
            data = os.pread(fd, os.fstat(fd).st_size, 0)
        else:
            offset, nbytes = (int(v) for v in index[np.ravel_multi_index(
                tuple(c % p for c, p in zip(ci, lay.per_shard)), lay.per_shard)])
            if offset == _MISSING or nbytes < 4:
                return False
            data = os.pread(fd, nbytes, offset)
            if len(data) != nbytes:
                return False
        if not _crc_ok(data):
            return False
        src, dst = [], []
        for c, k, n, (lo, hi) in zip(ci, lay.chunk, lay.shape, ranges):
            a, b = max(c * k, lo), min((c + 1) * k, hi, n)
            src.append(slice(a - c * k, b - c * k))
            dst.append(slice(a - lo, b - lo))
        target = out[tuple(dst)]
        whole = target.shape == lay.chunk and target.flags.c_contiguous
        try:
            if lay.blosc is not None and whole:  # the usual case: decoded in place, no second copy
                if int.from_bytes(data[4:8], "little") != nbytes_decoded:  # the blosc header's size
                    return False
                blosc.decompress(memoryview(data)[:-4], target)
                continue
            decoded = blosc.decompress(memoryview(data)[:-4]) if lay.blosc is not None else memoryview(data)[:-4]
        except Exception:
            return False
        if len(decoded) != nbytes_decoded:
            return False
        target[...] = np.frombuffer(decoded, lay.dtype).reshape(lay.chunk)[tuple(src)]
    return True


def write_direct(z, region: tuple[slice, ...], data: np.ndarray) -> bool:
    """Write ``data`` as the one whole chunk, or whole shard, ``region`` of an array, as zarr would (the
    same file bytes); ``False``, having written nothing, where zarr must write it.

    zarr's write of one chunk (an event-loop round trip, a directory check and
    buffer copies around the compressor) costs about as much as compressing it,
    and a shard of Register's stack has one such write per inner chunk.  A
    shard's inner chunks are encoded one at a time, each copied once, in zarr's (Morton) order, then its index
    (offset and length per inner chunk in C order, then the index's crc32c;
    zarr v3 sharding spec, index at the end); an inner chunk wholly beyond the
    array's end is not stored, as zarr does not store it.  The file is written
    whole to a ``.partial`` name and renamed, as zarr does, so a killed writer
    never leaves a torn chunk or shard under its name.
    """
    import uuid

    lay = _layout(z)
    if lay is None or len(region) != len(lay.shape):
        return False
    if not getattr(getattr(z, "config", None), "write_empty_chunks", False):
        return False  # zarr would leave out (and delete) fill-valued chunks: every chunk written is this writer's
    unit = tuple(c * p for c, p in zip(lay.chunk, lay.per_shard)) if lay.per_shard else lay.chunk
    key = []
    for s, c, n in zip(region, unit, lay.shape):
        if s.start is None or s.start % c or s.stop != min(s.start + c, n) or s.step not in (None, 1):
            return False
        key.append(s.start // c)
    data = np.asarray(data)
    if data.shape != tuple(s.stop - s.start for s in region):
        return False
    if lay.per_shard is not None:
        try:  # zarr's order of inner chunks in a shard file (an internal of zarr: else zarr writes it)
            from zarr.core.indexing import morton_order_iter
        except ImportError:
            return False
        order = list(morton_order_iter(lay.per_shard))
    if data.shape != unit:  # an edge chunk or shard is stored whole, the fill value beyond the array (zarr v3)
        whole = np.full(unit, lay.fill_value, lay.dtype)
        whole[tuple(slice(0, n) for n in data.shape)] = data
        data = whole
    path = _path(lay, tuple(key))
    os.makedirs(os.path.dirname(path), exist_ok=True)
    partial = f"{path}.{uuid.uuid4().hex}.partial"
    try:
        with open(partial, "wb") as f:
            if lay.per_shard is None:
                _write_encoded(f, lay, data)
            else:
                index = np.full((*lay.per_shard, 2), _MISSING, "<u8")
                offset = 0
                for ci in order:
                    if any(s.start + i * c >= n for s, i, c, n in zip(region, ci, lay.chunk, lay.shape)):
                        continue  # wholly beyond the array's end: not stored (zarr's index marks it missing)
                    inner = data[tuple(slice(i * c, (i + 1) * c) for i, c in zip(ci, lay.chunk))]
                    nbytes = _write_encoded(f, lay, inner)
                    index[ci] = (offset, nbytes)
                    offset += nbytes
                raw = index.tobytes()
                f.write(raw)
                f.write(_crc32c(raw))
        os.replace(partial, path)
    except BaseException:
        if os.path.exists(partial):
            os.remove(partial)
        raise
    return True


def _write_encoded(f, lay: _Layout, chunk: np.ndarray) -> int:
    """Write one whole chunk as its codecs encode it (``bytes`` -> ``blosc`` -> ``crc32c``); its length in bytes."""
    from numcodecs import Blosc

    payload = np.ascontiguousarray(chunk, lay.dtype).reshape(-1).view(np.uint8)
    encoded = Blosc.from_config(dict(lay.blosc)).encode(payload) if lay.blosc is not None else payload.tobytes()
    f.write(encoded)
    f.write(_crc32c(encoded))
    return len(encoded) + 4
