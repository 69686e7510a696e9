"""Artifacts in zarr: opening them read-only, writing a node's arrays chunk by chunk, completing them.

See :mod:`sbrdf_core.store` for the layout, integrity and confinement rules
these classes keep.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import shutil
import threading
import uuid
from collections import OrderedDict
from collections.abc import Mapping
from typing import Any

import numpy as np
import zarr

from ..artifacts import KINDS, ArtifactKind
from ..errors import ArtifactError
from ._digests import chunk_crc, file_digest, written
from ._layout import (
    _ARRAY_NAME,
    ARTIFACT_MARKER,
    MARKERS,
    TRASH,
    ArrayLayout,
    ChunkError,
    _all_keys,
    _clear_chunk_path,
    _fs,
    _is_local,
    _kill_point,
    _marker_name,
    _what,
    chunk_key,
    disk_errors,
    done_keys,
    inside_store,
    join,
    regular_file,
    special_entries,
)
from ._shards import read_direct, write_direct

#: One name for the store's messages, whichever private module logs them.
logger = logging.getLogger("sbrdf_core.store")


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
        if self.attrs.get("layout"):  # the arrays its node declared: no listing, which fails on one bad zarr.json
            return sorted(self.attrs["layout"])
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
        if not isinstance(z, zarr.Array):  # a group where the array should be
            raise ArtifactError(f"damaged artifact {self.url}: {name!r} is a group, not an array")
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
        if not self.z.shape:  # as NumPy: a 0-d array has no length
            raise TypeError("len() of unsized object")
        return int(self.z.shape[0])

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
    """Open an artifact read-only, checking its kind and that it is complete.

    A local artifact holding anything but plain files and directories (a link,
    a FIFO) is refused before anything in it is read: see :func:`special_entries`.
    """
    fs, root = _fs(url)
    if _is_local(fs) and os.path.lexists(root):
        odd = ([(".", _what(root, os.lstat(root).st_mode))] if os.path.islink(root) else special_entries(root))
        if odd:
            where = ", ".join(f"{rel} is {what}" for rel, what in odd[:3]) + (" ..." if len(odd) > 3 else "")
            raise ArtifactError(f"damaged artifact {url}: {where}; sbrdf writes only plain files and directories "
                                f"there and follows no link: `sbrdf verify --repair` removes them (not what a "
                                f"link points to)")
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
        self.local = _is_local(self.fs)

    def _metadata(self, path: str) -> bool | None:
        """Whether the metadata file at ``path`` exists (None: something that is not a plain file is there)."""
        if not self.local:
            return self.fs.exists(path)
        if not os.path.lexists(path):
            return False
        return True if regular_file(path) else None

    def attrs(self) -> dict | None:
        if not self._metadata(join(self.root, "zarr.json")):
            return None
        try:
            return dict(zarr.open_group(store=self.url, mode="r").attrs)
        except Exception:
            return None

    def state(self) -> str:
        """``missing``, ``complete`` (same token), ``partial`` (same token) or ``stale``."""
        if self._metadata(join(self.root, "zarr.json")) is False:
            return "missing"
        attrs = self.attrs()
        if attrs is None or attrs.get("token") != self.token or attrs.get("kind") != self.kind.kind:
            return "stale"
        return "complete" if attrs.get("complete") else "partial"

    def owned(self) -> bool:
        """Whether the directory is this node's artifact: its marker file, or (stores written
        before markers) group attributes of an sbrdf kind whose provenance names this node."""
        marker = join(self.root, ARTIFACT_MARKER)
        try:
            if self._metadata(marker):
                with self.fs.open(marker, "r") as f:
                    return json.load(f).get("node") == self.node
        except Exception:
            pass
        attrs = self.attrs() or {}
        node = attrs.get("node", (attrs.get("provenance") or {}).get("node"))
        return attrs.get("kind") in KINDS and node == self.node

    def _confined(self) -> None:
        """Refuse to write or delete unless the artifact path is inside the store and not itself a link."""
        inside_store(self.store, self.url)
        if self.local and os.path.islink(self.root):
            raise ArtifactError(f"{self.url} is a symbolic link to {os.readlink(self.root)}; sbrdf never writes or "
                                f"deletes through a link: remove the link (`sbrdf verify --repair {self.store}` "
                                f"removes it, not what it points to)")

    def remove(self) -> None:
        """Delete the artifact, once proven inside the store and this node's.

        Locally the directory is first renamed aside (one atomic step) and then
        deleted: a run killed while deleting leaves a hidden ``.sbrdf-trash-*``
        directory, emptied by the next :meth:`remove` or :meth:`prepare` of the
        node, never a half-deleted artifact that nothing proves is this node's.
        """
        self._confined()
        if not self.fs.exists(self.root) or (self.fs.isdir(self.root) and not self.fs.ls(self.root)):
            return  # nothing, or an empty directory: zarr creates the group in it
        if not self.owned():
            raise ArtifactError(f"{self.url} exists but is not the artifact of node {self.node!r} "
                                f"(no {ARTIFACT_MARKER} naming it); refusing to delete it: move it away")
        if not self.local:
            self.fs.rm(self.root, recursive=True)
            return
        trash = os.path.join(os.path.dirname(self.root), f"{TRASH}{self.node}-{uuid.uuid4().hex}")
        os.rename(self.root, trash)
        _kill_point(self.node, "removing")
        shutil.rmtree(trash)  # removes links found inside, never what they point to

    def _empty_trash(self) -> None:
        if not self.local:
            return
        parent = os.path.dirname(self.root)
        for name in os.listdir(parent) if os.path.isdir(parent) else ():
            path = os.path.join(parent, name)
            if name.startswith(f"{TRASH}{self.node}-") and not os.path.islink(path) and os.path.isdir(path):
                shutil.rmtree(path)

    def prepare(self, layouts: Mapping[str, ArrayLayout], attrs: Mapping[str, Any]) -> dict[str, set[str]]:
        """Create the group and arrays (or keep a partial one); return done chunk keys per array."""
        self._confined()
        for name in layouts:
            if not _ARRAY_NAME.fullmatch(name) or name.split("/")[0] == MARKERS:
                raise ArtifactError(f"{self.url}: output array name {name!r} is not a relative name of "
                                    f"letters, digits, '_', '-' and '/'")
        with disk_errors(self.store, f"the metadata of artifact {self.url}"):
            return self._prepare(layouts, attrs)

    def _prepare(self, layouts: Mapping[str, ArrayLayout], attrs: Mapping[str, Any]) -> dict[str, set[str]]:
        self._empty_trash()
        record = {name: lay.record() for name, lay in layouts.items()}
        state = self.state()
        if state == "partial" and (self.attrs() or {}).get("layout") != record:
            # The node now declares other shapes (its chunks do not fit), or the artifact was
            # begun before checksums and layouts were recorded: start it again.
            state = "stale"
        if state == "partial":
            return self._resume(layouts)
        if state != "missing" or self.fs.exists(self.root) or (self.local and os.path.lexists(self.root)):
            self.remove()
        _kill_point(self.node, "group")
        group = zarr.open_group(store=self.url, mode="w", attributes={
            **attrs, "kind": self.kind.kind, "version": self.kind.version, "token": self.token, "complete": False,
            "node": self.node, "layout": record})
        self.fs.pipe(join(self.root, ARTIFACT_MARKER), json.dumps({"node": self.node, "kind": self.kind.kind}).encode())
        _kill_point(self.node, "marker")
        for name, lay in layouts.items():
            self._create(group, name, lay)
        return {name: set() for name in layouts}

    def _create(self, group: zarr.Group, name: str, lay: ArrayLayout, overwrite: bool = False) -> None:
        """Create array ``name`` and its marker array (a kill between the two is resumed: see :meth:`_resume`)."""
        import warnings

        with warnings.catch_warnings():  # overwriting lists the group, whose marker file is no zarr node
            warnings.filterwarnings("ignore", message=".*not recognized as a component of a Zarr hierarchy")
            group.create_array(name, shape=lay.shape, chunks=lay.inner or lay.chunks,
                               shards=lay.chunks if lay.inner else None, dtype=lay.dtype, fill_value=lay.fill_value,
                               compressors=_codecs(), overwrite=overwrite)
            _kill_point(self.node, "array")
            grid = lay.grid or (1,)
            group.create_array(_marker_name(name), shape=grid, chunks=(1,) * len(grid), dtype="uint32", fill_value=0,
                               compressors=_codecs(), overwrite=overwrite)
        _kill_point(self.node, "markers")

    def _resume(self, layouts: Mapping[str, ArrayLayout]) -> dict[str, set[str]]:
        """Keep a partial artifact's written chunks; make whatever a killed or tampered run left unusable usable.

        A run killed while the arrays were being created leaves some without
        their ``zarr.json`` (or their marker array's): those are created now.
        An array whose metadata is not what the node declares, or not a plain
        file, is created again with its markers (its chunks are rewritten).
        Links, FIFOs and the like inside the artifact are removed (the link, never
        what it points to), and so is whatever stands where a chunk that is not
        done will be written (a directory, say), so that writing it cannot fail.
        """
        if self.local:
            for rel, what in special_entries(self.root):
                logger.warning("artifact %s: removing %s, %s (sbrdf writes only plain files there)", self.url, rel, what)
                os.unlink(os.path.join(self.root, rel))
        for leftover in (p for p in self.fs.find(self.root) if p.endswith(".partial")):
            self.fs.rm(leftover)  # a killed writer's temporary file; its chunk is rewritten
        group = None
        for name, lay in layouts.items():
            if not (self._array_ok(name, lay) and self._array_ok(_marker_name(name), None, lay)):
                if group is None:  # (a Group's truth value lists its members)
                    group = zarr.open_group(store=self.url, mode="r+")
                logger.info("artifact %s: creating array %r (and its done markers) again", self.url, name)
                self._create(group, name, lay, overwrite=True)
        # A marker whose chunk file is gone proves nothing any more: rewrite that chunk.
        done = {name: self.done(name) & written(self.fs, self.root, name, lay) for name, lay in layouts.items()}
        if self.local:
            for name, lay in layouts.items():
                for key in _all_keys(lay) - done[name]:
                    _clear_chunk_path(os.path.join(self.root, name), key, lay)
        return done

    def _array_ok(self, name: str, lay: ArrayLayout | None, markers_of: ArrayLayout | None = None) -> bool:
        """Whether array ``name``'s metadata is a plain file describing ``lay`` (or the marker grid of ``markers_of``)."""
        if not self._metadata(join(self.root, name, "zarr.json")):
            return False
        try:
            z = zarr.open_array(store=join(self.url, name), mode="r")
        except Exception:
            return False
        if markers_of is not None:
            return tuple(z.shape) == (markers_of.grid or (1,)) and z.dtype == np.uint32
        assert lay is not None, "an array's own layout, or the one whose markers it holds"
        return (tuple(z.shape), tuple(z.shards or z.chunks), np.dtype(z.dtype)) == (lay.shape, lay.chunks, np.dtype(lay.dtype))

    def done(self, name: str) -> set[str]:
        """Chunk keys (``"i.j.k"``) whose marker exists.  Only existence counts: a
        marker torn by a killed writer still proves its data chunk was complete.  A
        killed writer can also leave zarr's temporary ``<key>.<uuid>.partial`` file
        behind; it proves nothing and is not a chunk key."""
        return done_keys(self.fs, self.root, name)

    def mark_complete(self, layouts: Mapping[str, ArrayLayout], attrs: Mapping[str, Any]) -> None:
        """Set ``complete`` only after checking every chunk's marker exists; record the
        size and digest of the files kept beside the arrays, so a lost one is noticed."""
        _kill_point(self.node, "complete")
        with disk_errors(self.store, f"the metadata of artifact {self.url}"):
            self._mark_complete(layouts, attrs)
        _kill_point(self.node, "completed")

    def _mark_complete(self, layouts: Mapping[str, ArrayLayout], attrs: Mapping[str, Any]) -> None:
        for name, lay in layouts.items():
            missing = lay.nchunks - len(self.done(name))
            if missing:
                raise ArtifactError(f"{self.url}: {missing} chunks of {name!r} were not written; not marking complete")
        group = zarr.open_group(store=self.url, mode="r+")
        files = attrs.get("files", group.attrs.get("files")) or []
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
    # arenas kept as freed memory (sbrdf_core._runtime).
    data = block.astype(arr.dtype, copy=False)
    with disk_errors(url.rstrip("/").rsplit("/", 1)[0], f"artifact {url}, array {name!r}, chunk {chunk_key(index)}"):
        if not write_direct(arr, region, data):  # part of a shard, another store or codec: zarr writes it
            arr[region] = data
        marker = _open_cached(url, _marker_name(name), token)
        where = tuple(index) or (0,)
        crc = np.full((1,) * len(where), chunk_crc(data), np.uint32)
        if not write_direct(marker, tuple(slice(i, i + 1) for i in where), crc):
            marker[where] = crc
    _kill_point(url.rstrip("/").rsplit("/", 1)[-1], "chunk")
    return int(block.nbytes)


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
