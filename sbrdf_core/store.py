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
of the array ``_done/<name>``, whose grid mirrors the data array's chunk grid.  A run killed part-way leaves the markers of the
chunks it finished, and a re-run with the same token writes only the others.
The marker, not the chunk file, is the proof: zarr skips chunks that equal the
fill value and a killed writer can leave a torn chunk file, but a marker is
only created after its chunk was written whole.
"""

from __future__ import annotations

import math
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
from .errors import ArtifactError

__all__ = [
    "Artifact",
    "ArrayLayout",
    "ArtifactWriter",
    "open_artifact",
    "pose_major_chunks",
    "texel_tile",
    "write_chunk",
]

MARKERS = "_done"


def _fs(url: str) -> tuple[fsspec.AbstractFileSystem, str]:
    return fsspec.core.url_to_fs(url)


def join(url: str, *parts: str) -> str:
    return "/".join([url.rstrip("/"), *[p.strip("/") for p in parts]])


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

    def zarr_array(self, name: str) -> zarr.Array:
        try:
            return self.group[name]
        except KeyError:
            raise ArtifactError(f"{self.kind} at {self.url} has no array {name!r}; it has {self.names()}") from None

    def array(self, name: str):
        """Lazy dask array over the stored chunks (nothing is read yet)."""
        import dask.array as da

        z = self.zarr_array(name)
        return da.from_zarr(z, name=f"read-{name}-{self.token or 'x'}-{self.url}")

    def read(self, name: str) -> np.ndarray:
        """Read a (small) array into memory."""
        return self.zarr_array(name)[...]

    def nbytes_stored(self) -> int:
        fs, root = _fs(self.url)
        return int(sum(fs.du(root, total=False).values())) if fs.exists(root) else 0

    def __repr__(self) -> str:
        state = "complete" if self.complete else "INCOMPLETE"
        return f"<{self.kind} v{self.version} {state} at {self.url}>"


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
    if art.kind not in KINDS:  # plugins may declare kinds when they load (sbrdf_shading does)
        from .registry import default_registry

        default_registry()
    if art.kind not in KINDS:
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


def chunk_key(index: tuple[int, ...]) -> str:
    return ".".join(map(str, index)) or "0"


_CHUNK_KEY = re.compile(r"\d+(\.\d+)*")


def _marker_name(name: str) -> str:
    return f"{MARKERS}/{name.replace('/', '.')}"


class ArtifactWriter:
    """Creates or resumes one artifact and tracks which chunks are done."""

    def __init__(self, url: str, kind: ArtifactKind, token: str):
        self.url = url
        self.kind = kind
        self.token = token
        self.fs, self.root = _fs(url)

    def state(self) -> str:
        """``missing``, ``complete`` (same token), ``partial`` (same token) or ``stale``."""
        if not self.fs.exists(join(self.root, "zarr.json")):
            return "missing"
        try:
            attrs = dict(zarr.open_group(store=self.url, mode="r").attrs)
        except Exception:
            return "stale"
        if attrs.get("token") != self.token or attrs.get("kind") != self.kind.kind:
            return "stale"
        return "complete" if attrs.get("complete") else "partial"

    def prepare(self, layouts: Mapping[str, ArrayLayout], attrs: Mapping[str, Any]) -> dict[str, set[str]]:
        """Create the group and arrays (or keep a partial one); return done chunk keys per array."""
        state = self.state()
        if state == "partial":
            for leftover in (p for p in self.fs.find(self.root) if p.endswith(".partial")):
                self.fs.rm(leftover)  # a killed writer's temporary file; its chunk is rewritten
            return {name: self.done(name) for name in layouts}
        if state in ("stale", "complete"):
            self.fs.rm(self.root, recursive=True)
        group = zarr.open_group(store=self.url, mode="w")
        for name, lay in layouts.items():
            group.create_array(name, shape=lay.shape, chunks=lay.inner or lay.chunks, shards=lay.chunks if lay.inner else None,
                               dtype=lay.dtype, fill_value=lay.fill_value)
            grid = lay.grid or (1,)
            group.create_array(_marker_name(name), shape=grid, chunks=(1,) * len(grid), dtype="uint8", fill_value=0)
        group.attrs.update({**attrs, "kind": self.kind.kind, "version": self.kind.version, "token": self.token, "complete": False})
        return {name: set() for name in layouts}

    def done(self, name: str) -> set[str]:
        """Chunk keys (``"i.j.k"``) whose marker exists.  Only existence counts: a
        marker torn by a killed writer still proves its data chunk was complete.  A
        killed writer can also leave zarr's temporary ``<key>.<uuid>.partial`` file
        behind; it proves nothing and is not a chunk key."""
        path = join(self.root, _marker_name(name), "c")
        try:
            found = self.fs.find(path)
        except FileNotFoundError:
            return set()
        keys = (p[len(path) + 1:].replace("/", ".") for p in found)
        return {k for k in keys if _CHUNK_KEY.fullmatch(k)}

    def mark_complete(self, layouts: Mapping[str, ArrayLayout], attrs: Mapping[str, Any]) -> None:
        """Set ``complete`` only after checking every chunk's marker exists."""
        for name, lay in layouts.items():
            missing = lay.nchunks - len(self.done(name))
            if missing:
                raise ArtifactError(f"{self.url}: {missing} chunks of {name!r} were not written; not marking complete")
        group = zarr.open_group(store=self.url, mode="r+")
        group.attrs.update({**attrs, "complete": True})


#: Open zarr arrays per (url, name, token) in this process (LRU, so long-lived
#: workers running many graphs do not grow without bound).
_ARRAYS: OrderedDict[tuple[str, str, str], zarr.Array] = OrderedDict()
_ARRAYS_MAX = 512
_ARRAYS_LOCK = threading.Lock()


def write_chunk(block: np.ndarray, url: str, name: str, token: str, index: tuple[int, ...], region: tuple[slice, ...]) -> int:
    """Write one chunk then its done marker.  Runs inside dask tasks, on any worker.

    Idempotent: a task re-run after a lost worker rewrites the same bytes.
    """
    arr = _open_cached(url, name, token)
    block = np.asarray(block)
    expected = tuple(s.stop - s.start for s in region)
    if block.shape != expected:
        raise ArtifactError(f"{url}/{name}: chunk {index} has shape {block.shape}, expected {expected}")
    arr[region] = block.astype(arr.dtype, copy=False)
    marker = _open_cached(url, _marker_name(name), token)
    marker[tuple(index) or (0,)] = 1
    return int(block.nbytes)


def _open_cached(url: str, name: str, token: str) -> zarr.Array:
    key = (url, name, token)
    with _ARRAYS_LOCK:
        arr = _ARRAYS.get(key)
        if arr is None:
            arr = _ARRAYS[key] = zarr.open_array(store=join(url, name), mode="r+")
            while len(_ARRAYS) > _ARRAYS_MAX:
                _ARRAYS.popitem(last=False)
        else:
            _ARRAYS.move_to_end(key)
        return arr
