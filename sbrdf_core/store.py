"""How an artifact lives in zarr: layout, chunking, attributes, completion.

Every artifact is a zarr group with attributes

``kind``, ``version``
    which :class:`~sbrdf_core.artifacts.ArtifactKind` it is and its layout version;
``token``
    the node's cache key (kind, plugin and version, parameters, input tokens);
``complete``
    ``True`` only once every chunk of every array has been written;
``provenance``
    graph, node, parameters, plugin name and version, input digests.

Chunks are written by dask tasks, each followed by a *done marker*: one chunk
of the array ``_done/<name>``, whose grid mirrors the data array's chunk grid
(its value is the crc32c of the chunk's values: see :func:`write_chunk`).  A run killed part-way leaves the markers of the
chunks it finished, and a re-run with the same token writes only the others.
The marker, not the chunk file, is the proof: a killed writer can leave a torn
chunk file, but a marker is only created after its chunk was written whole.

Integrity (docs/reliability.md).  Every array is written with a ``crc32c``
codec after its compressor (:func:`_codecs`) in its codec chain, so a damaged chunk fails to decode
instead of reading back as other numbers, and every chunk is written even when
it equals the fill value, so a missing chunk file means a lost chunk, not an
empty one.  Arrays opened through :class:`Artifact` raise
:class:`ChunkError` naming the artifact, array and chunk.  The group records
the ``layout`` its node declared (shape, chunks, dtype per array), against
which :mod:`sbrdf_core.integrity` checks a cached artifact before reuse.

Confinement.  A node writes only below ``<store>/<node>``: names are checked
against :data:`NODE_NAME` at validation, every artifact path is proven inside
the store by :func:`inside_store`, and a directory is removed only when it
carries this node's marker file (:data:`ARTIFACT_MARKER`) or its group
attributes name this node.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import posixpath
import re
import threading
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import fsspec
import numpy as np
import zarr

from .artifacts import KINDS, ArtifactKind
from .chunk_files import read_direct, write_direct
from .errors import ArtifactError

__all__ = [
    "Artifact",
    "ArrayLayout",
    "ArtifactWriter",
    "ChunkError",
    "NODE_NAME",
    "inside_store",
    "open_artifact",
    "pose_major_chunks",
    "texel_tile",
    "write_chunk",
]

MARKERS = "_done"

#: What a node name may be: it becomes a directory of the store, so no path
#: separators, no ``.``/``..``, nothing empty, and short enough for any file system.
NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]{0,63}")

#: File in each artifact directory naming the node that owns it: the proof
#: that a directory may be removed (a directory with a ``zarr.json`` is not).
ARTIFACT_MARKER = ".sbrdf-artifact"

#: Array names (``params/rho_d``): relative, no ``.``/``..`` components.
_ARRAY_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]*(/[A-Za-z0-9_][A-Za-z0-9_-]*)*")


def _codecs():
    """Blosc (lz4, byte shuffle), then a crc32c checksum of the compressed bytes.

    Byte-shuffled lz4 rather than zstd: on float32 radiance and f_r it keeps
    11 % fewer bytes (shuffling groups the exponents) and encodes about five
    times faster, decodes about twice as fast; zstd (level 3) compressed at
    ~120 MB/s a core, which made every node that writes a scan's samples
    compression-bound, not disk-bound (Reflectance 7.0-9.6 s against 5.2-5.4 s
    at 0.57 GB, docs/cluster.md).  Stores written with zstd still read: the
    codecs are each array's own metadata.
    """
    from zarr.codecs import BloscCodec, Crc32cCodec

    return [BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"), Crc32cCodec()]


def _fs(url: str) -> tuple[fsspec.AbstractFileSystem, str]:
    return fsspec.core.url_to_fs(url)


def join(url: str, *parts: str) -> str:
    return "/".join([url.rstrip("/"), *[p.strip("/") for p in parts]])


def _is_local(fs) -> bool:
    return "file" in (fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,))


def inside_store(store: str, url: str) -> str:
    """Return ``url`` once proven strictly inside ``store``; raise :class:`ArtifactError` otherwise.

    Every path the runner writes or deletes goes through here first.  Local
    paths are resolved (``..`` and symbolic links) before the comparison, so
    neither a node name nor a link planted in the store leads out of it; the
    store root itself is refused too (writing a group there wipes the store).
    """
    fs, root = _fs(store)
    fs2, path = _fs(url)
    if _is_local(fs) != _is_local(fs2):
        raise ArtifactError(f"{url} is not in the store {store}; refusing to write or delete there")
    if _is_local(fs):
        root, path = os.path.realpath(root), os.path.realpath(path)
    else:
        root, path = posixpath.normpath("/" + root.lstrip("/")), posixpath.normpath("/" + path.lstrip("/"))
    if path == root or os.path.commonpath([root, path]) != root:
        raise ArtifactError(f"{url} resolves to {path}, outside the store {root}; refusing to write or delete there")
    return url


class ChunkError(ArtifactError):
    """A stored chunk cannot be read back: checksum mismatch, torn or foreign bytes."""

    def __init__(self, url: str, array: str, keys: list[str], cause: str):
        self.url, self.array, self.keys, self.cause = url, array, list(keys), cause
        where = f"chunk{'s' if len(keys) > 1 else ''} {', '.join(keys)}" if keys else "a chunk"
        super().__init__(f"damaged artifact {url}: array {array!r}, {where}: {cause}")

    def __reduce__(self):  # distributed pickles exceptions raised on workers
        return ChunkError, (self.url, self.array, self.keys, self.cause)


# ---------------------------------------------------------------------------
# chunking policies
# ---------------------------------------------------------------------------


#: Smallest automatic texel tile (see texel_tile).
MIN_TILE = 8


def pose_major_chunks(shape: tuple[int, ...]) -> tuple[int, ...]:
    """One pose per chunk: how captures arrive and how registration reads them."""
    return (1, *shape[1:])


def texel_tile(texels_vu: tuple[int, int], poses: int, channels: int = 3, itemsize: int = 4,
               target_bytes: int = 16 * 2**20, tile: int | None = None) -> int:
    """Edge of the square texel tile holding *all poses* of its texels in one chunk.

    Fitting needs every sample of a texel at once, so sampled reflectance is
    stored tile-major.  The tile is the largest power of two in [32, 128]
    (DESIGN.md) whose chunk stays under ``target_bytes``; past 1024 samples
    per texel (4 channels) even 32² would not, and the tile keeps halving down
    to 8², so that a chunk, and the memory a worker needs to transpose or fit
    one, stays bounded however many poses a scan has (a fixed 32² tile of 8000
    poses would be a 131 MB chunk).  Never larger than the grid; an explicit
    ``tile`` wins.
    """
    if tile is None:
        per_texel = max(poses, 1) * channels * itemsize
        tile = 128
        while tile > MIN_TILE and tile * tile * per_texel > target_bytes:
            tile //= 2
    return max(1, min(tile, max(texels_vu)))


# ---------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------


class Artifact:
    """A read-only view of one artifact; arrays come back as lazy dask arrays."""

    def __init__(self, url: str, group: zarr.Group):
        self.url = url
        self.group = group
        self.attrs: dict[str, Any] = dict(group.attrs)

    kind = property(lambda self: self.attrs.get("kind"))
    version = property(lambda self: self.attrs.get("version"))
    token = property(lambda self: self.attrs.get("token"))
    complete = property(lambda self: bool(self.attrs.get("complete")))
    provenance = property(lambda self: self.attrs.get("provenance", {}))

    def names(self) -> list[str]:
        return sorted(name for name, m in members(self.group)
                      if isinstance(m, zarr.Array) and not name.startswith(MARKERS))

    def zarr_array(self, name: str) -> CheckedArray:
        """The stored array; reads that fail to decode raise :class:`ChunkError`."""
        try:
            z = self.group[name]
        except KeyError:
            raise ArtifactError(f"{self.kind} at {self.url} has no array {name!r}; it has {self.names()}") from None
        except Exception as e:  # an unreadable zarr.json
            raise ArtifactError(f"damaged artifact {self.url}: array {name!r} metadata cannot be read: {e}") from None
        return CheckedArray(z, self.url, name)

    def array(self, name: str):
        """Lazy dask array over the stored chunks (nothing is read yet)."""
        import dask.array as da

        z = self.zarr_array(name)
        return da.from_array(z, chunks=z.chunks, name=f"read-{name}-{self.token or 'x'}-{self.url}",
                             asarray=False, fancy=False, meta=np.empty((0,) * z.ndim, z.dtype))

    def read(self, name: str) -> np.ndarray:
        """Read a (small) array into memory."""
        return self.zarr_array(name)[...]

    def nbytes_stored(self) -> int:
        fs, root = _fs(self.url)
        return int(sum(fs.du(root, total=False).values())) if fs.exists(root) else 0

    def __repr__(self) -> str:
        state = "complete" if self.complete else "INCOMPLETE"
        return f"<{self.kind} v{self.version} {state} at {self.url}>"


class CheckedArray:
    """A zarr array whose reads name the damaged chunk when decoding fails.

    zarr reports a checksum mismatch as a bare ``ValueError``; raised inside a
    node's task it would name neither the artifact nor the chunk.  Everything
    but ``[...]`` is the underlying :class:`zarr.Array`.
    """

    def __init__(self, z: zarr.Array, url: str, name: str):
        self.z, self.url, self.name = z, url, name

    def __getattr__(self, attr):
        if attr.startswith("__") or attr in ("z", "url", "name"):  # unpickling: not yet set
            raise AttributeError(attr)
        return getattr(self.z, attr)

    def __len__(self) -> int:
        return len(self.z)

    def __dask_tokenize__(self):  # cheap and deterministic (no pickling of the zarr array)
        return ("sbrdf-stored-array", self.url, self.name, tuple(self.z.shape), str(self.z.dtype))

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self[...], dtype=dtype)

    def __getitem__(self, sel):
        try:
            # Chunk-aligned reads straight from the chunk files where the layout allows (the same
            # values, several times faster than zarr's per-chunk reads of a shard); else zarr.
            direct = read_direct(self.z, sel)
            return self.z[sel] if direct is None else direct
        except (IndexError, TypeError):  # a bad selection, not a damaged chunk
            raise
        except Exception as e:
            cause = "crc32c checksum mismatch" if "checksum" in str(e) else f"{type(e).__name__}: {e}"
            raise ChunkError(self.url, self.name, self._bad_chunks(sel), cause) from None

    def _bad_chunks(self, sel) -> list[str]:
        """The stored chunks (shards) overlapping ``sel`` that fail on their own; at most 8 tried bad."""
        step = self.z.shards or self.z.chunks
        sel = sel if isinstance(sel, tuple) else (sel,)
        ranges = []
        for axis, (n, c) in enumerate(zip(self.z.shape, step)):
            s = sel[axis] if axis < len(sel) and sel[axis] is not Ellipsis else slice(None)
            if isinstance(s, (int, np.integer)):
                s = slice(int(s) % n, int(s) % n + 1)
            if not isinstance(s, slice):
                s = slice(None)
            lo, hi, _ = s.indices(n)
            ranges.append(range(lo // c, max(lo // c, (hi - 1) // c) + 1) if hi > lo else range(0))
        bad = []
        for index in itertools.product(*ranges):
            region = tuple(slice(i * c, min((i + 1) * c, n)) for i, c, n in zip(index, step, self.z.shape))
            try:
                self.z[region]
            except Exception:
                bad.append(chunk_key(index))
                if len(bad) == 8:
                    break
        return bad


def members(group: zarr.Group):
    """All members of a group, quietly skipping files kept beside the arrays (EXR, PNG)."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*not recognized as a component of a Zarr hierarchy")
        return list(group.members(max_depth=None))


def open_artifact(url: str, kind: ArtifactKind | str | tuple | None = None, require_complete: bool = True) -> Artifact:
    """Open an artifact read-only, checking its kind and that it is complete."""
    try:
        group = zarr.open_group(store=url, mode="r")
    except Exception as e:
        raise ArtifactError(f"no artifact at {url}: {e}") from None
    art = Artifact(url, group)
    if art.kind not in KINDS:  # plugins' kinds are known once a Registry has loaded them
        if isinstance(art.kind, str) and art.kind and art.attrs.get("version") is not None:
            raise ArtifactError(f"{url} holds a {art.kind!r}, a kind no loaded plugin declares "
                                f"(known: {', '.join(sorted(KINDS))}); is its plugin installed and enabled?")
        raise ArtifactError(f"{url} is not an sbrdf artifact (kind attribute is {art.kind!r})")
    if kind is not None:
        wanted = kind if isinstance(kind, tuple) else (kind,)
        names = [k.kind if isinstance(k, ArtifactKind) else k for k in wanted]
        if art.kind not in names:
            raise ArtifactError(f"{url} holds a {art.kind}, expected {' or '.join(names)}")
    if require_complete and not art.complete:
        raise ArtifactError(f"{art.kind} at {url} is incomplete (its run was interrupted); re-run the graph to finish it")
    return art


# ---------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ArrayLayout:
    """Shape, chunking and dtype of one output array.

    ``chunks`` is what one task writes (and one done marker covers).  With
    ``inner``, each of those is a zarr *shard* of ``inner``-sized chunks that
    readers fetch on their own: a writer can produce a whole pose block in one
    task while a reader takes one texel tile of it.
    """

    shape: tuple[int, ...]
    chunks: tuple[int, ...]
    dtype: str
    fill_value: Any = 0
    inner: tuple[int, ...] | None = None

    @property
    def grid(self) -> tuple[int, ...]:
        return tuple(math.ceil(s / c) if c else 0 for s, c in zip(self.shape, self.chunks))

    @property
    def nchunks(self) -> int:
        return int(np.prod(self.grid)) if self.shape else 1

    def record(self) -> dict:
        """What the group's ``layout`` attribute keeps of it (JSON)."""
        return {"shape": list(self.shape), "chunks": list(self.chunks), "dtype": str(np.dtype(self.dtype)),
                "inner": list(self.inner) if self.inner else None}


def chunk_key(index: tuple[int, ...]) -> str:
    return ".".join(map(str, index)) or "0"


_CHUNK_KEY = re.compile(r"\d+(\.\d+)*")


def _marker_name(name: str) -> str:
    return f"{MARKERS}/{name.replace('/', '.')}"


def done_keys(fs, root: str, name: str) -> set[str]:
    """Chunk keys of array ``name`` of the artifact at ``root`` whose done marker exists."""
    path = join(root, _marker_name(name), "c")
    try:
        found = fs.find(path)
    except FileNotFoundError:
        return set()
    keys = (p[len(path) + 1:].replace("/", ".") for p in found)
    return {k for k in keys if _CHUNK_KEY.fullmatch(k)}


class ArtifactWriter:
    """Creates or resumes one artifact and tracks which chunks are done.

    ``store`` is the store the artifact belongs to and ``node`` its node name
    (by default the parent directory and the last path component of ``url``):
    nothing outside the store is written, and only a directory marked as this
    node's artifact is removed.
    """

    def __init__(self, url: str, kind: ArtifactKind, token: str, store: str | None = None, node: str | None = None):
        self.url = url
        self.kind = kind
        self.token = token
        self.store = store if store is not None else url.rstrip("/").rsplit("/", 1)[0]
        self.node = node if node is not None else url.rstrip("/").rsplit("/", 1)[-1]
        self.fs, self.root = _fs(url)

    def attrs(self) -> dict | None:
        try:
            return dict(zarr.open_group(store=self.url, mode="r").attrs)
        except Exception:
            return None

    def state(self) -> str:
        """``missing``, ``complete`` (same token), ``partial`` (same token) or ``stale``."""
        if not self.fs.exists(join(self.root, "zarr.json")):
            return "missing"
        attrs = self.attrs()
        if attrs is None or attrs.get("token") != self.token or attrs.get("kind") != self.kind.kind:
            return "stale"
        return "complete" if attrs.get("complete") else "partial"

    def owned(self) -> bool:
        """Whether the directory is this node's artifact: its marker file, or (stores written
        before markers) group attributes of an sbrdf kind whose provenance names this node."""
        try:
            with self.fs.open(join(self.root, ARTIFACT_MARKER), "r") as f:
                return json.load(f).get("node") == self.node
        except Exception:
            pass
        attrs = self.attrs() or {}
        node = attrs.get("node", (attrs.get("provenance") or {}).get("node"))
        return attrs.get("kind") in KINDS and node == self.node

    def remove(self) -> None:
        """Delete the artifact, once proven inside the store and this node's."""
        inside_store(self.store, self.url)
        if not self.fs.exists(self.root) or (self.fs.isdir(self.root) and not self.fs.ls(self.root)):
            return  # nothing, or an empty directory: zarr creates the group in it
        if not self.owned():
            raise ArtifactError(f"{self.url} exists but is not the artifact of node {self.node!r} "
                                f"(no {ARTIFACT_MARKER} naming it); refusing to delete it: move it away")
        self.fs.rm(self.root, recursive=True)

    def prepare(self, layouts: Mapping[str, ArrayLayout], attrs: Mapping[str, Any]) -> dict[str, set[str]]:
        """Create the group and arrays (or keep a partial one); return done chunk keys per array."""
        inside_store(self.store, self.url)
        for name in layouts:
            if not _ARRAY_NAME.fullmatch(name) or name.split("/")[0] == MARKERS:
                raise ArtifactError(f"{self.url}: output array name {name!r} is not a relative name of "
                                    f"letters, digits, '_', '-' and '/'")
        record = {name: lay.record() for name, lay in layouts.items()}
        state = self.state()
        if state == "partial" and (self.attrs() or {}).get("layout") != record:
            # The node now declares other shapes (its chunks do not fit), or the artifact was
            # begun before checksums and layouts were recorded: start it again.
            state = "stale"
        if state == "partial":
            for leftover in (p for p in self.fs.find(self.root) if p.endswith(".partial")):
                self.fs.rm(leftover)  # a killed writer's temporary file; its chunk is rewritten
            from .integrity import written

            # A marker whose chunk file is gone proves nothing any more: rewrite that chunk.
            return {name: self.done(name) & written(self.fs, self.root, name, lay) for name, lay in layouts.items()}
        if state != "missing" or self.fs.exists(self.root):
            self.remove()
        group = zarr.open_group(store=self.url, mode="w", attributes={
            **attrs, "kind": self.kind.kind, "version": self.kind.version, "token": self.token, "complete": False,
            "node": self.node, "layout": record})
        self.fs.pipe(join(self.root, ARTIFACT_MARKER), json.dumps({"node": self.node, "kind": self.kind.kind}).encode())
        for name, lay in layouts.items():
            group.create_array(name, shape=lay.shape, chunks=lay.inner or lay.chunks, shards=lay.chunks if lay.inner else None,
                               dtype=lay.dtype, fill_value=lay.fill_value, compressors=_codecs())
            grid = lay.grid or (1,)
            group.create_array(_marker_name(name), shape=grid, chunks=(1,) * len(grid), dtype="uint32", fill_value=0,
                               compressors=_codecs())
        return {name: set() for name in layouts}

    def done(self, name: str) -> set[str]:
        """Chunk keys (``"i.j.k"``) whose marker exists.  Only existence counts: a
        marker torn by a killed writer still proves its data chunk was complete.  A
        killed writer can also leave zarr's temporary ``<key>.<uuid>.partial`` file
        behind; it proves nothing and is not a chunk key."""
        return done_keys(self.fs, self.root, name)

    def mark_complete(self, layouts: Mapping[str, ArrayLayout], attrs: Mapping[str, Any]) -> None:
        """Set ``complete`` only after checking every chunk's marker exists; record the
        size and digest of the files kept beside the arrays, so a lost one is noticed."""
        for name, lay in layouts.items():
            missing = lay.nchunks - len(self.done(name))
            if missing:
                raise ArtifactError(f"{self.url}: {missing} chunks of {name!r} were not written; not marking complete")
        group = zarr.open_group(store=self.url, mode="r+")
        files = attrs.get("files", group.attrs.get("files")) or []
        from .integrity import file_digest

        digests = {f: file_digest(self.fs, join(self.root, f)) for f in files if isinstance(f, str)}
        group.attrs.update({**attrs, "file_digests": digests, "complete": True})


#: Open zarr arrays per (url, name, token) in this process (LRU, so long-lived
#: workers running many graphs do not grow without bound).
_ARRAYS: OrderedDict[tuple[str, str, str], zarr.Array] = OrderedDict()
_ARRAYS_MAX = 512
_ARRAYS_LOCK = threading.Lock()


def write_chunk(block: np.ndarray, url: str, name: str, token: str, index: tuple[int, ...], region: tuple[slice, ...]) -> int:
    """Write one chunk then its done marker.  Runs inside dask tasks, on any worker.

    Idempotent: a task re-run after a lost worker rewrites the same bytes.
    The marker holds the crc32c of the chunk's values, so ``sbrdf verify``
    also notices a chunk that decodes but is not the one written there (a
    chunk file copied or swapped from elsewhere passes its own checksum).
    """
    arr = _open_cached(url, name, token)
    block = np.asarray(block)
    expected = tuple(s.stop - s.start for s in region)
    if block.shape != expected:
        raise ArtifactError(f"{url}/{name}: chunk {index} has shape {block.shape}, expected {expected}")
    # No contiguous copy of a strided block (radiance is a view of Register's packed (k, V, U, 4)
    # block, f_r of Reflectance's tile): write_direct copies a whole chunk once, or a shard one
    # inner chunk at a time (as zarr's encoding did), and chunk_crc reads it a slice at a time.
    # A whole copy (24 MiB a pose block), and the crc's bytes copy of it, were each the size of
    # the block again in every writing thread, and such block-sized temporaries are what glibc's
    # arenas kept as freed memory (sbrdf_core.memory).
    data = block.astype(arr.dtype, copy=False)
    if not write_direct(arr, region, data):  # part of a shard, another store or codec: zarr writes it
        arr[region] = data
    marker = _open_cached(url, _marker_name(name), token)
    where = tuple(index) or (0,)
    crc = np.full((1,) * len(where), chunk_crc(data), np.uint32)
    if not write_direct(marker, tuple(slice(i, i + 1) for i in where), crc):
        marker[where] = crc
    return int(block.nbytes)


def chunk_crc(data: np.ndarray) -> int:
    """crc32c of a chunk's values (C order), as its done marker keeps it.

    Read in place when contiguous, else one slice of the first axis at a time
    (crc32c extends over concatenated bytes: the same value), never as a whole copy.
    """
    import google_crc32c

    data = np.asarray(data)
    if data.ndim == 0 or data.flags.c_contiguous:
        return int(google_crc32c.value(np.ascontiguousarray(data).reshape(-1).view(np.uint8)))
    crc = 0
    for part in data:
        crc = google_crc32c.extend(crc, np.ascontiguousarray(part).reshape(-1).view(np.uint8))
    return int(crc)


def _open_cached(url: str, name: str, token: str) -> zarr.Array:
    key = (url, name, token)
    with _ARRAYS_LOCK:
        arr = _ARRAYS.get(key)
        if arr is None:
            # Every chunk written, fill-valued or not: a missing chunk file is then a lost chunk.
            with zarr.config.set({"array.write_empty_chunks": True}):  # captured by the array when opened
                arr = zarr.open_array(store=join(url, name), mode="r+")
            _ARRAYS[key] = arr
            while len(_ARRAYS) > _ARRAYS_MAX:
                _ARRAYS.popitem(last=False)
        else:
            _ARRAYS.move_to_end(key)
        return arr
