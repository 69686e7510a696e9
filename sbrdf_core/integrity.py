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

import getpass
import hashlib
import json
import logging
import os
import socket
import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np
import zarr

from .errors import ArtifactError, RunError
from .store import (
    _ARRAY_NAME,
    _CHUNK_KEY,
    ARTIFACT_MARKER,
    MARKERS,
    ArrayLayout,
    _fs,
    _is_local,
    _marker_name,
    chunk_crc,
    chunk_key,
    done_keys,
    inside_store,
    join,
    members,
)

LOCK_FILE = ".sbrdf.lock"
HOLDER_FILE = ".sbrdf.lock.json"

logger = logging.getLogger(__name__)


def file_digest(fs, path: str) -> dict | None:
    """Size and sha256 of a side file (None when it does not exist)."""
    if not fs.exists(path):
        return None
    h = hashlib.sha256()
    with fs.open(path, "rb") as f:
        while block := f.read(1 << 20):
            h.update(block)
    return {"size": int(fs.size(path)), "sha256": h.hexdigest()}


def written(fs, root: str, name: str, lay: ArrayLayout) -> set[str]:
    """Keys of the chunk files of array ``name`` that exist and can hold their 4-byte checksum.

    Every chunk is written (fill-valued ones too), so a key missing here is a lost chunk.
    """
    base = join(root, name, "c")
    if not lay.shape:
        return {"0"} if fs.exists(base) and fs.size(base) >= 4 else set()
    try:
        found = fs.find(base, detail=True)
    except FileNotFoundError:
        return set()
    keys = {p[len(base) + 1:].replace("/", "."): info.get("size", 0) for p, info in found.items()}
    return {k for k, size in keys.items() if _CHUNK_KEY.fullmatch(k) and size >= 4}


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
        return ", ".join(parts) or "nothing"


def _layouts(attrs: dict) -> dict[str, ArrayLayout]:
    return {name: ArrayLayout(tuple(r["shape"]), tuple(r["chunks"]), r["dtype"],
                              inner=tuple(r["inner"]) if r.get("inner") else None)
            for name, r in (attrs.get("layout") or {}).items()}


def _keys(lay: ArrayLayout) -> set[str]:
    return {chunk_key(i) for i in np.ndindex(*lay.grid)} if lay.shape else {"0"}


def check_artifact(url: str, full: bool = False) -> Damage:
    """Check one artifact (see the module docstring); an empty :class:`Damage` means sound."""
    fs, root = _fs(url)
    d = Damage(url)
    if not fs.exists(join(root, "zarr.json")):
        d.add("its group's zarr.json is missing", rebuild=True)
        return d
    try:
        attrs = dict(zarr.open_group(store=url, mode="r").attrs)
    except Exception as e:
        d.add(f"its group's zarr.json cannot be read ({type(e).__name__})", rebuild=True)
        return d
    d.kind = attrs.get("kind")
    layouts = _layouts(attrs)
    if not layouts:  # written before layouts were recorded: no inventory, chunks read as they are
        layouts = {n: ArrayLayout(tuple(z.shape), tuple(z.shards or z.chunks), str(z.dtype))
                   for n, z in members(zarr.open_group(store=url, mode="r"))
                   if isinstance(z, zarr.Array) and not n.startswith(MARKERS)} if full else {}
        legacy = True
    else:
        legacy = False
    for name, lay in sorted(layouts.items()):
        try:
            z = zarr.open_array(store=join(url, name), mode="r")
            zarr.open_array(store=join(url, _marker_name(name)), mode="r") if not legacy else None
        except Exception as e:
            d.add(f"array {name!r}: metadata missing or unreadable ({type(e).__name__})", rebuild=True)
            continue
        got = (tuple(z.shape), tuple(z.shards or z.chunks), str(z.dtype))
        want = (lay.shape, lay.chunks, str(np.dtype(lay.dtype)))
        if got != want:
            d.add(f"array {name!r} is shape {got[0]} chunks {got[1]} {got[2]}; its node declared "
                  f"shape {want[0]} chunks {want[1]} {want[2]}", rebuild=True)
            continue
        if not legacy:
            lost = _keys(lay) - (done_keys(fs, root, name) & written(fs, root, name, lay))
            if lost:
                d.add(f"array {name!r}: {len(lost)} chunk{'s' if len(lost) > 1 else ''} lost "
                      f"(file missing or truncated, or no done marker): {', '.join(sorted(lost)[:5])}"
                      + (" ..." if len(lost) > 5 else ""), array=name, keys=lost)
        if full:
            crcs = _marker_crcs(url, name, d) if not legacy else None
            for index in (np.ndindex(*lay.grid) if lay.shape else [()]):
                key = chunk_key(index)
                if key in d.chunks.get(name, ()):
                    continue
                region = tuple(slice(i * c, min((i + 1) * c, n)) for i, c, n in zip(index, lay.chunks, lay.shape))
                try:
                    values = z[region]
                except Exception as e:
                    why = "crc32c checksum mismatch" if "checksum" in str(e) else f"{type(e).__name__}: {str(e)[:120]}"
                    d.add(f"array {name!r}, chunk {key}: {why}", array=name, keys=[key], deep=True)
                    continue
                if crcs is not None and chunk_crc(values) != crcs[index or (0,)]:
                    d.add(f"array {name!r}, chunk {key}: its values are not the ones written there (crc32c differs "
                          f"from its done marker's)", array=name, keys=[key], deep=True)
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
        elif full and rec and file_digest(fs, path)["sha256"] != rec["sha256"]:
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
        return m[...].astype(np.int64)
    except Exception:
        out = np.full(m.shape, -1, np.int64)
        for index in np.ndindex(*m.shape):
            try:
                out[index] = m[index]
            except Exception:
                key = chunk_key(index)
                d.add(f"array {name!r}, chunk {key}: its done marker cannot be read", array=name, keys=[key], deep=True)
        return out


def drop_chunks(url: str, chunks: dict[str, set[str] | None]) -> None:
    """Mark chunks for rewriting: delete their done markers and data, and the ``complete`` flag.

    ``None`` for an array drops every chunk of it.  The next run with the same
    token resumes the artifact and writes exactly these chunks (and finishes
    the node again: its side files are rewritten).
    """
    fs, root = _fs(url)
    group = zarr.open_group(store=url, mode="r+")
    layouts = _layouts(dict(group.attrs))
    for name, keys in chunks.items():
        if not _ARRAY_NAME.fullmatch(name):
            raise ArtifactError(f"{url}: {name!r} is not an array name")
        if keys is None:
            keys = _keys(layouts[name]) if name in layouts else set()
        for key in keys:
            if not _CHUNK_KEY.fullmatch(key):
                raise ArtifactError(f"{url}: {key!r} is not a chunk key")
            for path in (join(root, _marker_name(name), "c", *key.split(".")), join(root, name, "c", *key.split("."))):
                if fs.isfile(path):
                    fs.rm(path)
    group.attrs["complete"] = False


def repair(damage: Damage, store: str, node: str) -> None:
    """Turn ``damage`` into work for the next run (see :func:`drop_chunks`); a rebuild removes the artifact."""
    from .store import ArtifactWriter

    inside_store(store, damage.url)
    if damage.rebuild:
        w = ArtifactWriter(damage.url, None, "", store=store, node=node)  # type: ignore[arg-type]
        w.remove()
    else:
        drop_chunks(damage.url, damage.chunks)


def artifact_dirs(store: str) -> tuple[list[str], list[str]]:
    """URLs of the store's artifacts (directories with a ``zarr.json`` or an artifact marker),
    and of directories holding zarr data but neither: broken beyond proof of whose they are."""
    fs, root = _fs(store)
    if not fs.exists(root):
        return [], []
    ours, unproven = [], []
    for p in sorted(fs.ls(root, detail=False)):
        name = p.rstrip("/").rsplit("/", 1)[-1]
        if not fs.isdir(p) or name.startswith("."):
            continue
        url = store.rstrip("/") + "/" + name
        if fs.exists(join(p, "zarr.json")) or fs.exists(join(p, ARTIFACT_MARKER)):
            ours.append(url)
        elif fs.glob(join(p, "*", "zarr.json")):
            unproven.append(url)
    return ours, unproven


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

    def __init__(self, store: str, wait: bool | float = False, what: str = ""):
        self.store, self.what = store, what
        self.timeout = -1 if wait is True else (0 if wait is False else float(wait))
        self.lock = None

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
        os.makedirs(root, exist_ok=True)
        self.holder = os.path.join(root, HOLDER_FILE)
        self.lock = FileLock(os.path.join(root, LOCK_FILE), timeout=self.timeout)
        try:
            self.lock.acquire()
        except Timeout:
            self.lock = None
            waited = f" (waited {self.timeout:g} s)" if self.timeout > 0 else ""
            raise StoreBusy(f"store {root} is in use by {self._holder_text()}{waited}; wait for that run to "
                            f"finish, or run with --wait") from None
        self.me = {"pid": os.getpid(), "host": socket.gethostname(), "user": _user(), "what": self.what,
                   "started": datetime.now(UTC).isoformat(timespec="seconds")}
        tmp = f"{self.holder}.{os.getpid()}.{id(self)}.tmp"
        with open(tmp, "w") as f:
            json.dump(self.me, f)
        os.replace(tmp, self.holder)
        return self

    def _holder_text(self) -> str:
        for _ in range(20):  # the holder writes its file just after taking the lock
            try:
                with open(self.holder) as f:
                    h = json.load(f)
                return (f"pid {h.get('pid')} on {h.get('host')} (user {h.get('user')}, {h.get('what') or 'a run'}) "
                        f"since {h.get('started')}")
            except (OSError, ValueError):
                time.sleep(0.05)
        return "another process (its holder file is missing)"

    def __exit__(self, *exc) -> None:
        if self.lock is None:
            return
        if isinstance(self.lock, S3Lease):
            self.lock.release()
            self.lock = None
            return
        try:
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
