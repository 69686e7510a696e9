"""Where an artifact's files are and what they are called: names, paths, chunk keys, layouts, confinement.

Nothing here opens zarr, and fsspec is imported only when a file system is
opened, so the graph validator and the node kinds use these names without
loading the storage engine.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import posixpath
import re
import shutil
import signal
import stat
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ArtifactError

if TYPE_CHECKING:
    import fsspec


MARKERS = "_done"

#: Prefix of a directory :meth:`ArtifactWriter.remove` renamed aside before deleting it (hidden: not an artifact).
TRASH = ".sbrdf-trash-"

#: What a node name may be: it becomes a directory of the store, so no path
#: separators, no ``.``/``..``, nothing empty, and short enough for any file system.
NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]{0,63}")

#: File in each artifact directory naming the node that owns it: the proof
#: that a directory may be removed (a directory with a ``zarr.json`` is not).
ARTIFACT_MARKER = ".sbrdf-artifact"

#: Array names (``params/rho_d``): relative, no ``.``/``..`` components.
_ARRAY_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]*(/[A-Za-z0-9_][A-Za-z0-9_-]*)*")


def _fs(url: str) -> tuple[fsspec.AbstractFileSystem, str]:
    import fsspec  # here, not at import: validating a graph joins paths without opening a file system

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
    with _KILL_LOCK:
        _KILL_COUNTS[point] = _KILL_COUNTS.get(point, 0) + 1
        if _KILL_COUNTS[point] != int(nth[0] if nth else 1):
            return
    os.kill(os.getpid(), getattr(signal, sig))
    if sig == "SIGINT":  # delivered to the main thread; this thread waits for it there
        import time

        time.sleep(5)


_KILL_COUNTS: dict[str, int] = {}
_KILL_LOCK = threading.Lock()


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
