"""Is a stored artifact still what its node wrote?  And who is writing this store?

Two levels of checking (docs/reliability.md):

* :func:`check_artifact` without ``full`` is what the runner does before it
  reuses a cached artifact.  It reads metadata and file listings, never a
  chunk: every array's ``zarr.json`` against the layout its node declared
  (shape, chunks, dtype), the inventory of chunk files against the done
  markers (a chunk file that is gone, or too short to hold its checksum), and
  the files kept beside the arrays (present, recorded size).
* with ``full`` (``sbrdf verify``) it also decodes every chunk, so each
  checksum is tested, and hashes the side files.

What was found is a :class:`Damage`, and :func:`repair` turns it into work
for the next run: lost or unreadable chunks have their done markers dropped
(the run rewrites exactly those), a lost side file makes the node finish
again, and damaged metadata makes the node recompute the whole artifact.

:class:`StoreLock` is the store's lock: one run (or verify) at a time (on S3,
:class:`S3Lease`: a leased object written with conditional puts).
"""

from __future__ import annotations

import errno
import getpass
import json
import logging
import os
import socket
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np
import zarr

from ..errors import ArtifactError, RunError
from ._artifact import ArtifactWriter, members
from ._digests import chunk_crc, file_digest, written
from ._layout import (
    _ARRAY_NAME,
    _CHUNK_KEY,
    ARTIFACT_MARKER,
    MARKERS,
    NODE_NAME,
    ArrayLayout,
    _fs,
    _is_local,
    _marker_name,
    _what,
    chunk_key,
    disk_errors,
    done_keys,
    inside_store,
    join,
    regular_file,
    remove_unfollowed,
    special_entries,
)

LOCK_FILE = ".sbrdf.lock"
HOLDER_FILE = ".sbrdf.lock.json"

logger = logging.getLogger("sbrdf_core.store")


@dataclass
class Damage:
    """What is wrong with one artifact, and what the next run has to redo."""

    url: str
    kind: str | None = None
    problems: list[str] = field(default_factory=list)
    chunks: dict[str, set[str]] = field(default_factory=dict)  # array -> chunk keys to rewrite
    rebuild: bool = False  # metadata damaged: recompute the whole artifact
    files: bool = False  # side files lost: finish the node again
    deep: bool = False  # found only by reading chunks (the runner's reuse check cannot see it)
    unlink: list[str] = field(default_factory=list)  # links, FIFOs...: removed themselves, never followed
    complete: bool = True  # False: an interrupted run's artifact, resumed by the next run
    notes: list[str] = field(default_factory=list)  # not damage: what a resuming run will do

    def __bool__(self) -> bool:
        return bool(self.problems)

    def add(self, message: str, *, array: str | None = None, keys=(), rebuild=False, files=False, deep=False):
        self.problems.append(message)
        if array is not None:
            self.chunks.setdefault(array, set()).update(keys)
        self.rebuild |= rebuild
        self.files |= files
        self.deep |= deep

    def plan(self) -> str:
        """What the next run recomputes (after :func:`repair`)."""
        if self.rebuild:
            return "the whole artifact"
        parts = [f"{len(k)} chunk{'s' if len(k) != 1 else ''} of {a!r}" for a, k in sorted(self.chunks.items()) if k]
        if self.files:
            parts.append("its side files")
        return ", ".join(parts) or ("the rest of the artifact" if not self.complete else "nothing")


def _layouts(attrs: dict) -> dict[str, ArrayLayout]:
    return {name: ArrayLayout(tuple(r["shape"]), tuple(r["chunks"]), r["dtype"],
                              inner=tuple(r["inner"]) if r.get("inner") else None)
            for name, r in (attrs.get("layout") or {}).items()}


def _keys(lay: ArrayLayout) -> set[str]:
    return {chunk_key(i) for i in np.ndindex(*lay.grid)} if lay.shape else {"0"}


def _metadata_file(fs, path: str) -> bool | None:
    """Whether a metadata file exists (None: something that is not a plain file stands there)."""
    if not _is_local(fs):
        return fs.exists(path)
    if not os.path.lexists(path):
        return False
    return True if regular_file(path) else None


def _odd_entries(d: Damage, root: str, layouts: dict[str, ArrayLayout]) -> None:
    """Links, FIFOs, devices inside a local artifact: damage, repaired by removing them (never what a link
    points to).  Inside an array's chunk folder its chunks are rewritten; elsewhere the artifact is."""
    for rel, what in special_entries(root):
        d.unlink.append(rel)
        path = rel.replace(os.sep, "/")
        for name, lay in layouts.items():
            for array in (name, _marker_name(name)):
                if path == f"{array}/c" or path.startswith(f"{array}/c/"):
                    d.add(f"{rel} is {what}: sbrdf writes only plain files there and follows no link out of "
                          f"an artifact", array=name, keys=_keys(lay))
                    break
            else:
                continue
            break
        else:
            d.add(f"{rel} is {what}: sbrdf writes only plain files and directories in an artifact and follows "
                  f"no link", rebuild=True)


def check_artifact(url: str, full: bool = False) -> Damage:
    """Check one artifact (see the module docstring); an empty :class:`Damage` means sound.

    An incomplete artifact (an interrupted run's) is checked for what would stop
    or mislead the run that resumes it: its metadata, and, with ``full``, the
    chunks it already counts as done.  Chunks not written yet are not damage.
    """
    fs, root = _fs(url)
    d = Damage(url)
    local = _is_local(fs)
    if local and os.path.islink(root):
        d.unlink.append(".")
        d.add(f"the artifact directory is a symbolic link to {os.readlink(root)}: a run refuses to write through it",
              rebuild=True)
        return d
    if local and os.path.lexists(root) and not os.path.isdir(root):
        d.add("the artifact path is not a directory", rebuild=True)
        return d
    group_meta = _metadata_file(fs, join(root, "zarr.json"))
    if group_meta is None or not group_meta:
        if local:
            _odd_entries(d, root, {})
        if not d.problems:
            d.add("its group's zarr.json is missing", rebuild=True)
        return d
    try:
        attrs: dict[str, Any] = dict(zarr.open_group(store=url, mode="r").attrs)
    except Exception as e:
        d.add(f"its group's zarr.json cannot be read ({type(e).__name__})", rebuild=True)
        if local:
            _odd_entries(d, root, {})
        return d
    d.kind = attrs.get("kind")
    d.complete = bool(attrs.get("complete"))
    if local:  # before any other read: a FIFO blocks its reader, a link leads out of the store
        _odd_entries(d, root, _layouts(attrs))
        if d:
            return d
    layouts = _layouts(attrs)
    if not layouts:  # written before layouts were recorded: no inventory, chunks read as they are
        layouts = {n: ArrayLayout(tuple(z.shape), tuple(z.shards or z.chunks), str(z.dtype))
                   for n, z in members(zarr.open_group(store=url, mode="r"))
                   if isinstance(z, zarr.Array) and not n.startswith(MARKERS)} if full else {}
        legacy = True
    else:
        legacy = False
    for name, lay in sorted(layouts.items()):
        metas = (name,) if legacy else (name, _marker_name(name))
        present = [_metadata_file(fs, join(root, m, "zarr.json")) for m in metas]
        if not d.complete and not legacy and all(p is False for p in present):
            d.notes.append(f"array {name!r} not created yet: the resuming run creates it")
            continue
        try:
            if not all(present):
                raise FileNotFoundError("zarr.json missing" if None not in present else "zarr.json not a plain file")
            z = zarr.open_array(store=join(url, name), mode="r")
            m = zarr.open_array(store=join(url, _marker_name(name)), mode="r") if not legacy else None
        except Exception as e:
            d.add(f"array {name!r}: metadata missing or unreadable ({type(e).__name__})", rebuild=True)
            continue
        got = (tuple(z.shape), tuple(z.shards or z.chunks), str(z.dtype))
        want = (lay.shape, lay.chunks, str(np.dtype(lay.dtype)))
        if got != want:
            d.add(f"array {name!r} is shape {got[0]} chunks {got[1]} {got[2]}; its node declared "
                  f"shape {want[0]} chunks {want[1]} {want[2]}", rebuild=True)
            continue
        if m is not None and (tuple(m.shape) != (lay.grid or (1,)) or m.dtype != np.uint32):
            d.add(f"array {name!r}: its done markers are shape {tuple(m.shape)} {m.dtype}, not the chunk grid "
                  f"{lay.grid or (1,)} uint32", rebuild=True)
            continue
        if not legacy:
            have = done_keys(fs, root, name) & written(fs, root, name, lay)
            lost = _keys(lay) - have
            if lost and d.complete:
                d.add(f"array {name!r}: {len(lost)} chunk{'s' if len(lost) > 1 else ''} lost "
                      f"(file missing or truncated, or no done marker): {', '.join(sorted(lost)[:5])}"
                      + (" ..." if len(lost) > 5 else ""), array=name, keys=lost)
        if full:
            crcs = _marker_crcs(url, name, d) if not legacy else None
            for index in (np.ndindex(*lay.grid) if lay.shape else [()]):
                key = chunk_key(index)
                if key in d.chunks.get(name, ()) or (not legacy and key not in have):
                    continue  # lost, or (an incomplete artifact) not written yet: the next run writes it
                region = tuple(slice(i * c, min((i + 1) * c, n)) for i, c, n in zip(index, lay.chunks, lay.shape))
                try:
                    values = np.asarray(z[region])
                except Exception as e:
                    why = "crc32c checksum mismatch" if "checksum" in str(e) else f"{type(e).__name__}: {str(e)[:120]}"
                    d.add(f"array {name!r}, chunk {key}: {why}", array=name, keys=[key], deep=True)
                    continue
                if crcs is not None and chunk_crc(values) != crcs[index or (0,)]:
                    d.add(f"array {name!r}, chunk {key}: its values are not the ones written there (crc32c differs "
                          f"from its done marker's)", array=name, keys=[key], deep=True)
    if not d.complete:
        return d  # side files are written when the node finishes
    recorded = attrs.get("file_digests") or {}
    for f in attrs.get("files") or []:
        path = join(root, str(f))
        try:
            inside_store(url, join(url, str(f)))
        except ArtifactError as e:
            d.add(str(e))
            continue
        if not fs.exists(path):
            d.add(f"file {f} is missing", files=True)
        elif (rec := recorded.get(f)) and fs.size(path) != rec["size"]:
            d.add(f"file {f} is {fs.size(path)} bytes, {rec['size']} were written", files=True)
        elif full and rec and (file_digest(fs, path) or {}).get("sha256") != rec["sha256"]:  # None: gone since
            d.add(f"file {f}: its sha256 differs from the one recorded when it was written", files=True, deep=True)
    return d


def _marker_crcs(url: str, name: str, d: Damage) -> np.ndarray | None:
    """The crc32c each chunk had when written (None for stores whose markers hold 1);
    a marker chunk that cannot be read is damage of its data chunk (-1)."""
    try:
        m = zarr.open_array(store=join(url, _marker_name(name)), mode="r")
    except Exception:
        return None
    if m.dtype != np.uint32:
        return None
    try:
        return np.asarray(m[...]).astype(np.int64)
    except Exception:
        out = np.full(m.shape, -1, np.int64)
        for index in np.ndindex(*m.shape):
            try:
                out[index] = m[index]
            except Exception:
                key = chunk_key(index)
                d.add(f"array {name!r}, chunk {key}: its done marker cannot be read", array=name, keys=[key], deep=True)
        return out


def _remove_local(root: str, rel: str) -> None:
    """Remove ``rel`` below the local directory ``root``, following no link (:func:`.store.remove_unfollowed`)."""
    remove_unfollowed(root, [p for p in rel.split("/") if p])


def drop_chunks(url: str, chunks: Mapping[str, set[str] | None]) -> None:
    """Mark chunks for rewriting: delete their done markers and data, and the ``complete`` flag.

    ``None`` for an array drops every chunk of it.  The next run with the same
    token resumes the artifact and writes exactly these chunks (and finishes
    the node again: its side files are rewritten).  Locally no link is followed:
    a chunk directory linked out of the store is removed as a link.
    """
    fs, root = _fs(url)
    local = _is_local(fs)
    if local and os.path.islink(root):
        raise ArtifactError(f"{url} is a symbolic link; refusing to delete through it")
    group = zarr.open_group(store=url, mode="r+")
    layouts = _layouts(dict(group.attrs))
    for name, keys in chunks.items():
        if not _ARRAY_NAME.fullmatch(name):
            raise ArtifactError(f"{url}: {name!r} is not an array name")
        if keys is None:
            keys = _keys(layouts[name]) if name in layouts else set()
        scalar = name in layouts and not layouts[name].shape
        for key in keys:
            if not _CHUNK_KEY.fullmatch(key):
                raise ArtifactError(f"{url}: {key!r} is not a chunk key")
            parts = [] if scalar else key.split(".")
            for array in (_marker_name(name), name):
                if local:
                    _remove_local(root, "/".join([array, "c", *parts]))
                else:
                    path = join(root, array, "c", *parts)
                    if fs.isfile(path):
                        fs.rm(path)
    group.attrs["complete"] = False


def repair(damage: Damage, store: str, node: str) -> None:
    """Turn ``damage`` into work for the next run (see :func:`drop_chunks`); a rebuild removes the artifact.

    Links, FIFOs and devices inside the artifact (or the artifact path itself
    when it is a link) are removed first, each as itself: what a link points to
    is never touched.
    """
    fs, root = _fs(damage.url)
    if _is_local(fs) and damage.unlink:
        if damage.unlink == ["."]:
            if os.path.islink(root):
                os.unlink(root)  # the link only: the store inside_store would resolve it to is not ours
            return
        inside_store(store, damage.url)
        for rel in damage.unlink:
            _remove_local(root, rel.replace(os.sep, "/"))
    inside_store(store, damage.url)
    with disk_errors(store, f"the repair of artifact {damage.url}"):
        if damage.rebuild:
            w = ArtifactWriter(damage.url, None, "", store=store, node=node)  # type: ignore[arg-type]
            w.remove()
        else:
            drop_chunks(damage.url, damage.chunks)


def artifact_dirs(store: str) -> tuple[list[str], list[str]]:
    """URLs of the store's artifacts (directories with a ``zarr.json`` or an artifact marker),
    and of directories holding zarr data but neither: broken beyond proof of whose they are.
    Links are neither: see :func:`stray_entries`."""
    fs, root = _fs(store)
    if not fs.exists(root):
        return [], []
    local = _is_local(fs)
    ours, unproven = [], []
    for p in sorted(fs.ls(root, detail=False)):
        name = p.rstrip("/").rsplit("/", 1)[-1]
        if name.startswith(".") or (local and os.path.islink(p)) or not fs.isdir(p):
            continue
        url = store.rstrip("/") + "/" + name
        if fs.exists(join(p, "zarr.json")) or fs.exists(join(p, ARTIFACT_MARKER)) or (
                local and os.path.lexists(join(p, "zarr.json"))):
            ours.append(url)
        elif fs.glob(join(p, "*", "zarr.json")):
            unproven.append(url)
    return ours, unproven


def stray_entries(store: str) -> list[tuple[str, str, bool]]:
    """What stands in a local store where an artifact directory would, but is none: ``(url, why, removable)``.

    A link (to another store, say) is followed by nothing sbrdf does and is
    removable (the link only).  A plain file or a FIFO named like a node makes
    a run of that node refuse; it is not sbrdf's to delete.
    """
    fs, root = _fs(store)
    if not _is_local(fs) or not os.path.isdir(root):
        return []
    out = []
    for name in sorted(os.listdir(root)):
        path = os.path.join(root, name)
        url = store.rstrip("/") + "/" + name
        if name.startswith("."):
            continue
        if os.path.islink(path):
            out.append((url, f"a symbolic link to {os.readlink(path)}, not an artifact: a run of node {name!r} "
                             f"refuses to write through it", True))
        elif not os.path.isdir(path) and NODE_NAME.fullmatch(name):
            out.append((url, f"{_what(path, os.lstat(path).st_mode) if not regular_file(path) else 'a plain file'} "
                             f"where node {name!r}'s artifact directory would be: a run of that node refuses to "
                             f"replace it", False))
    return out


# ---------------------------------------------------------------------------
# the store lock
# ---------------------------------------------------------------------------


class StoreBusy(RunError):
    """Another run holds the store."""


class StoreLock:
    """One writer per store: a :mod:`filelock` lock file inside the store, held for a whole run.

    The holder (pid, host, user, start time, what it runs) is written beside
    the lock so a refused run can say who holds it.  The lock is an OS lock
    on an open file: it works across threads (each lock object opens its own
    file) and processes, and a killed holder releases it.  On a dask cluster
    the runner process holds it while the workers write chunks on its behalf.
    On S3 (``s3://``) the lock is :class:`S3Lease`: an object created with a
    conditional put.  Other stores that are not local paths (``memory://``,
    ``gs://``...) are not locked: a warning says so.

    ``wait``: ``False`` refuses at once, ``True`` waits for ever, a number waits that many seconds.
    """

    def __init__(self, store: str, wait: bool | float = False, what: str = "", read_only: bool = False):
        self.store, self.what = store, what
        self.timeout = -1 if wait is True else (0 if wait is False else float(wait))
        self.lock: Any = None  # a FileLock, an S3Lease, or None while not held
        #: Whether a store this process cannot write may be used without writing (``sbrdf verify``):
        #: then a shared lock is taken on the existing lock file, read-only, and :attr:`note` says so.
        self.read_only = read_only
        self.note: str | None = None
        self._shared: int | None = None

    def __enter__(self) -> StoreLock:
        from filelock import FileLock, Timeout

        fs, root = _fs(self.store)
        if not _is_local(fs):
            if "s3" in (fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)):
                self.lock = S3Lease(fs, root, self.store, self.timeout, self.what)
                self.lock.acquire()
            else:
                logger.warning("store %s is not locked: only local paths and s3:// stores can be; make sure no "
                               "other run writes it at the same time", self.store)
            return self
        self.holder = os.path.join(root, HOLDER_FILE)
        lock_path = os.path.join(root, LOCK_FILE)
        for path in (lock_path, self.holder):
            if os.path.lexists(path) and not regular_file(path):
                raise RunError(f"store {root}: {os.path.basename(path)} is {_what(path, os.lstat(path).st_mode)}, "
                               f"not the lock file sbrdf writes; refusing to lock through it (it would write "
                               f"or block where it leads). Remove it (the link, not what it points to) and run again")
        if self.read_only and os.path.isdir(root) and not os.access(root, os.W_OK):
            return self._enter_read_only(root, lock_path)
        os.makedirs(root, exist_ok=True)
        self.lock = FileLock(lock_path, timeout=self.timeout)
        try:
            self.lock.acquire()
        except Timeout:
            self.lock = None
            waited = f" (waited {self.timeout:g} s)" if self.timeout > 0 else ""
            raise StoreBusy(f"store {root} is in use by {self._holder_text()}{waited}; wait for that run to "
                            f"finish, or run with --wait") from None
        except OSError as e:
            self.lock = None
            if self.read_only and e.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
                return self._enter_read_only(root, lock_path)
            raise RunError(f"store {root}: cannot take the lock {lock_path}: {e.strerror or e}") from None
        self.me = {"pid": os.getpid(), "host": socket.gethostname(), "user": _user(), "what": self.what,
                   "started": datetime.now(UTC).isoformat(timespec="seconds")}
        tmp = f"{self.holder}.{os.getpid()}.{id(self)}.tmp"
        try:
            with disk_errors(self.store, f"the lock holder file {self.holder}"):
                with open(tmp, "w") as f:
                    json.dump(self.me, f)
                os.replace(tmp, self.holder)  # replaces a name, never writes through a link
        except BaseException:
            if os.path.lexists(tmp):
                os.unlink(tmp)
            self.lock.release()
            self.lock = None
            raise
        return self

    def _enter_read_only(self, root: str, lock_path: str) -> StoreLock:
        """A store this process cannot write: a shared ``flock`` on the existing lock file, opened read-only
        (a run holds it exclusively, so this still waits for or refuses a running run); no lock file, no lock."""
        import fcntl

        try:
            fd = os.open(lock_path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except FileNotFoundError:
            self.note = (f"store {root} cannot be written by this process: verified read-only, without a lock (it "
                         f"has no lock file; no run by this user can be writing it)")
            return self
        start = time.monotonic()
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if self.timeout == 0 or (self.timeout > 0 and time.monotonic() - start >= self.timeout):
                    os.close(fd)
                    raise StoreBusy(f"store {root} is in use by {self._holder_text()}; wait for that run to "
                                    f"finish, or use --wait") from None
                time.sleep(0.1)
        self._shared = fd
        self.note = f"store {root} cannot be written by this process: verified read-only, under a shared lock"
        return self

    def _holder_text(self) -> str:
        for _ in range(20):  # the holder writes its file just after taking the lock
            try:
                if not regular_file(self.holder):
                    raise OSError("not a plain file")
                with open(self.holder) as f:
                    h = json.load(f)
                return (f"pid {h.get('pid')} on {h.get('host')} (user {h.get('user')}, {h.get('what') or 'a run'}) "
                        f"since {h.get('started')}")
            except (OSError, ValueError):
                time.sleep(0.05)
        return "another process (its holder file is missing)"

    def __exit__(self, *exc) -> None:
        if self._shared is not None:
            os.close(self._shared)  # releases the shared flock
            self._shared = None
        if self.lock is None:
            return
        if isinstance(self.lock, S3Lease):
            self.lock.release()
            self.lock = None
            return
        try:
            if regular_file(self.holder):
                with open(self.holder) as f:
                    if json.load(f) == self.me:
                        os.remove(self.holder)
        except (OSError, ValueError):
            pass
        self.lock.release()
        self.lock = None


class S3Lease:
    """The store lock on S3: ``<store>/.sbrdf.lock.json``, created with a conditional put.

    ``PutObject`` with ``If-None-Match: *`` creates the object only if it does
    not exist, so of two runs exactly one gets it (S3 since 2024; moto too).  It
    holds the holder's pid, host, user, graph, start time and ``expires``, a
    lease of :attr:`LEASE_S` seconds that a thread renews every third of it with
    ``If-Match`` on the object's ETag (so a holder that lost the lock notices).
    A killed holder cannot release it: the lock is taken over, with ``If-Match``
    on the stale object's ETag (one taker wins), once its lease has expired, or
    at once when its holder was a process of this host that no longer exists.
    Release deletes the object with ``If-Match`` (only our own lock).
    """

    #: Seconds a holder's lock lasts without renewal (``SBRDF_S3_LOCK_LEASE``).
    LEASE_S = float(os.environ.get("SBRDF_S3_LOCK_LEASE", 120))
    POLL_S = 1.0

    def __init__(self, fs, root: str, store: str, timeout: float, what: str):
        self.fs, self.store, self.timeout, self.what = fs, store, timeout, what
        self.bucket, self.key, _ = fs.split_path(join(root, HOLDER_FILE))
        self.etag: str | None = None
        self.lost = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _body(self) -> bytes:
        now = time.time()
        self.me = {"pid": os.getpid(), "host": socket.gethostname(), "user": _user(), "what": self.what,
                   "started": getattr(self, "started", None) or datetime.now(UTC).isoformat(timespec="seconds"),
                   "expires": now + self.LEASE_S, "lease_s": self.LEASE_S}
        self.started = self.me["started"]
        return json.dumps(self.me).encode()

    def _put(self, **cond) -> bool:
        try:
            out = self.fs.call_s3("put_object", Bucket=self.bucket, Key=self.key, Body=self._body(), **cond)
        except Exception as e:
            if _precondition_failed(e):
                return False
            raise
        self.etag = out["ETag"]
        return True

    def _current(self) -> tuple[dict | None, str | None]:
        """The lock object's holder and ETag, read in one request (None when there is none)."""
        from fsspec.asyn import sync

        async def get():
            out = await self.fs._call_s3("get_object", Bucket=self.bucket, Key=self.key)
            async with out["Body"] as body:
                return await body.read(), out["ETag"]

        try:
            data, etag = sync(self.fs.loop, get)
        except FileNotFoundError:
            return None, None
        try:
            return json.loads(data), etag
        except ValueError:
            return {}, etag

    def _stale(self, h: dict) -> bool:
        if time.time() > float(h.get("expires", 0)):
            return True
        if h.get("host") == socket.gethostname() and isinstance(h.get("pid"), int):
            try:
                os.kill(h["pid"], 0)
            except ProcessLookupError:
                return True
            except OSError:
                return False
        return False

    def acquire(self) -> None:
        start = time.monotonic()
        while True:
            if self._put(IfNoneMatch="*"):
                break
            h, etag = self._current()
            if h is not None and self._stale(h):
                if self._put(IfMatch=etag):
                    logger.warning("store %s: took over the lock of %s (expired or its process is gone)",
                                   self.store, _holder_words(h))
                    break
                continue
            if h is None:
                continue  # released meanwhile: try again at once
            waited = time.monotonic() - start
            if self.timeout == 0 or (self.timeout > 0 and waited >= self.timeout):
                w = f" (waited {self.timeout:g} s)" if self.timeout > 0 else ""
                raise StoreBusy(f"store {self.store} is in use by {_holder_words(h)}{w}; wait for that run to "
                                f"finish, or run with --wait (a killed run's lock expires "
                                f"{datetime.fromtimestamp(float(h.get('expires', 0)), UTC).isoformat(timespec='seconds')})")
            time.sleep(self.POLL_S)
        self._thread = threading.Thread(target=self._renew, name="sbrdf-s3-lock", daemon=True)
        self._thread.start()

    def _renew(self) -> None:
        while not self._stop.wait(self.LEASE_S / 3):
            try:
                if not self._put(IfMatch=self.etag):
                    self.lost = True
                    logger.error("store %s: this run's lock was taken over by another run; stop one of them",
                                 self.store)
                    return
            except Exception as e:  # network: try again at the next renewal
                logger.warning("store %s: could not renew the lock: %s", self.store, e)

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self.lost or self.etag is None:
            return
        try:
            self.fs.call_s3("delete_object", Bucket=self.bucket, Key=self.key, IfMatch=self.etag)
        except Exception as e:
            if not _precondition_failed(e):
                logger.warning("store %s: could not remove the lock: %s", self.store, e)
        self.fs.invalidate_cache()


def _precondition_failed(e: Exception) -> bool:
    text = str(e)
    return isinstance(e, FileExistsError) or any(
        w in text for w in ("PreconditionFailed", "pre-conditions", "412", "ConditionalRequestConflict"))


def _holder_words(h: dict) -> str:
    return (f"pid {h.get('pid')} on {h.get('host')} (user {h.get('user')}, {h.get('what') or 'a run'}) "
            f"since {h.get('started')}")


def _user() -> str:
    try:
        return getpass.getuser()
    except Exception:
        return ""
