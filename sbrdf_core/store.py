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
attributes name this node.  Inside an artifact there are only plain files and
directories: an artifact path that is a link is refused, and a link, FIFO or
device found below it (:func:`special_entries`) is removed as itself before
anything there is read, written or deleted, never followed.

Resume.  A partial artifact always resumes, wherever its run was killed:
arrays whose metadata a kill left missing are created again (:meth:`ArtifactWriter.prepare`).
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import json
import logging
import math
import os
import posixpath
import re
import shutil
import signal
import stat
import threading
import uuid
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

#: Prefix of a directory :meth:`ArtifactWriter.remove` renamed aside before deleting it (hidden: not an artifact).
TRASH = ".sbrdf-trash-"

logger = logging.getLogger(__name__)

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


def regular_file(path: str) -> bool:
    """Whether ``path`` is a plain file (not a link, FIFO, socket, device or directory).

    Metadata is opened only then: opening a FIFO put in place of a ``zarr.json``
    blocks for ever, holding the store lock.
    """
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def _what(path: str, mode: int) -> str:
    if stat.S_ISLNK(mode):
        try:
            return f"a symbolic link to {os.readlink(path)}"
        except OSError:
            return "a symbolic link"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a plain file"


def special_entries(root: str) -> list[tuple[str, str]]:
    """Entries below a local artifact directory that are neither plain files nor directories.

    ``(path relative to root, what it is)``.  sbrdf writes only plain files and
    directories there, so anything else was put there by something else: a link
    would lead reads and writes (and a repair's deletes) out of the store, a FIFO
    or device would block the reader.  Links are listed, never followed.
    """
    out = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in dirnames + filenames:
            path = os.path.join(dirpath, name)
            try:
                mode = os.lstat(path).st_mode
            except OSError:
                continue
            if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
                out.append((os.path.relpath(path, root), _what(path, mode)))
    return sorted(out)


def no_space(e: OSError, store: str, what: str) -> ArtifactError | None:
    """``e`` as a clear :class:`ArtifactError` when it is a full disk (or quota); else ``None``."""
    if e.errno not in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
        return None
    full = "no space left on the device" if e.errno == errno.ENOSPC else "the disk quota is exhausted"
    return ArtifactError(f"store {store}: {full} writing {what}. Free space on the file system of {store} (or run "
                         f"with another --store), then re-run: what was already written is kept")


@contextlib.contextmanager
def disk_errors(store: str, what: str):
    """Turn a full disk while writing ``what`` into :func:`no_space`'s error; other errors pass unchanged."""
    try:
        yield
    except OSError as e:
        clear = no_space(e, store, what)
        if clear is None:
            raise
        raise clear from e


def _kill_point(node: str, point: str) -> None:
    """Test-only: ``SBRDF_TEST_KILL_AT=node:point:SIGNAL[:n]`` makes this process send itself SIGNAL the n-th
    time ``node`` passes ``point``, so tests can kill a run exactly between two writes (tests/core/test_kill_resume.py)."""
    spec = os.environ.get("SBRDF_TEST_KILL_AT")
    if not spec:
        return
    want_node, want_point, sig, *nth = spec.split(":")
    if (want_node, want_point) != (node, point):
        return
    with _ARRAYS_LOCK:
        _KILL_COUNTS[point] = _KILL_COUNTS.get(point, 0) + 1
        if _KILL_COUNTS[point] != int(nth[0] if nth else 1):
            return
    os.kill(os.getpid(), getattr(signal, sig))
    if sig == "SIGINT":  # delivered to the main thread; this thread waits for it there
        import time

        time.sleep(5)


_KILL_COUNTS: dict[str, int] = {}


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


def _all_keys(lay: ArrayLayout) -> set[str]:
    return {chunk_key(i) for i in np.ndindex(*lay.grid)} if lay.shape else {"0"}


def remove_unfollowed(root: str, parts: list[str], keep_file: bool = False) -> None:
    """Remove ``root/parts...`` (local) without following a link on the way.

    Every directory between ``root`` and the end must be a real directory (not
    a link): where one is not, that entry is removed instead (as a link, never
    what it points to) and the path below it is gone with it.  A directory at
    the end is removed with its contents (links inside it as links); a plain
    file at the end is kept when ``keep_file``.
    """
    path = root
    for i, part in enumerate(parts):
        path = os.path.join(path, part)
        try:
            mode = os.lstat(path).st_mode
        except FileNotFoundError:
            return
        last = i == len(parts) - 1
        if stat.S_ISDIR(mode) and not last:
            continue
        if stat.S_ISREG(mode) and last and keep_file:
            return
        if stat.S_ISDIR(mode):
            shutil.rmtree(path)
        else:
            os.unlink(path)
        return


def _clear_chunk_path(array_root: str, key: str, lay: ArrayLayout) -> None:
    """Remove whatever stands where chunk ``key`` of a local array will be written, but is not a chunk file.

    A directory (or a file where a directory of the key belongs) there makes
    every write of the chunk fail.  Only entries inside the array's own ``c``
    directory are touched, links are removed as links, and a chunk file that
    is a plain file is left for the writer to replace.
    """
    remove_unfollowed(array_root, ["c", *key.split(".")] if lay.shape else ["c"], keep_file=True)


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
        from .integrity import written

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
