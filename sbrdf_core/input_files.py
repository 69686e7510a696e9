"""Bounded reads of the files a graph names: regular files only, a size limit, never a blocking open.

Every file a graph or scene names (the graph itself, scenes, meshes,
environment maps, measured tables) is user input: a path to ``/dev/zero``
would be read until memory runs out, ``/dev/urandom`` or a FIFO would block
``validate`` forever, and a multi-gigabyte file would be read whole before
anything could say it is wrong.  So before a byte is read:

- the path is ``stat``-ed and must be a regular file (through symbolic links):
  a directory, FIFO, socket or device is refused, naming the file and what it is;
- its size must be at most the limit for its kind (:data:`TEXT_LIMIT` for YAML
  and other text, :data:`DATA_LIMIT` for binary data), each overridable by an
  environment variable;
- it is opened with ``O_NONBLOCK`` and checked again with ``fstat``, so a file
  swapped for a FIFO between the two checks cannot block the open, and at most
  limit + 1 bytes are read (a file that grew meanwhile is refused, not read whole).

Failures raise :class:`InputFileError`, an :class:`OSError` whose ``strerror``
says what is wrong and whose ``filename`` is the path, so callers that already
report ``OSError`` as ``<file>: cannot read ... file: <strerror>`` report these too.
"""

from __future__ import annotations

import errno
import os
import stat

#: Largest YAML or text input (graphs, scenes, OBJ and ASTM text), bytes; ``SBRDF_MAX_TEXT_BYTES`` overrides.
TEXT_LIMIT = 64 * 2**20
#: Largest binary input (meshes, images, measured tables), bytes; ``SBRDF_MAX_INPUT_BYTES`` overrides.
DATA_LIMIT = 4 * 2**30

TEXT_ENV = "SBRDF_MAX_TEXT_BYTES"
DATA_ENV = "SBRDF_MAX_INPUT_BYTES"


class InputFileError(OSError):
    """A file a graph names that is not read: not a regular file, or larger than the limit."""

    def __init__(self, code: int, message: str, path: str | os.PathLike):
        super().__init__(code, message, str(path))

    def __str__(self) -> str:
        return f"{self.filename}: {self.strerror}"


def limit(text: bool) -> int:
    """The size limit in bytes for text (``text=True``) or binary inputs, from the environment when set there."""
    name, default = (TEXT_ENV, TEXT_LIMIT) if text else (DATA_ENV, DATA_LIMIT)
    raw = os.environ.get(name, "").strip()
    if not raw:
        return default
    try:
        value = int(raw)
    except ValueError:
        raise InputFileError(errno.EINVAL, f"environment variable {name}={raw!r} is not a number of bytes",
                             name) from None
    return max(value, 0)


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _check_stat(st: os.stat_result, path: str | os.PathLike, text: bool, max_bytes: int | None) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(errno.EINVAL, f"it is {_kind(st.st_mode)}, not a regular file; only regular files "
                                           "are read", path)
    cap = limit(text) if max_bytes is None else max_bytes
    if st.st_size > cap:
        env = TEXT_ENV if text else DATA_ENV
        raise InputFileError(errno.EFBIG, f"it is {st.st_size} bytes, more than the {cap}-byte limit for "
                                          f"{'text' if text else 'data'} inputs (set {env} to raise it)", path)


def check_file(path: str | os.PathLike, text: bool = False, max_bytes: int | None = None) -> int:
    """Refuse ``path`` unless it is a regular file within the size limit; returns its size.

    For files a library opens by name (images, meshes read by trimesh): the
    checks of :func:`read_bytes` without the read.
    """
    st = os.stat(path)
    _check_stat(st, path, text, max_bytes)
    return st.st_size


def read_bytes(path: str | os.PathLike, text: bool = False, max_bytes: int | None = None) -> bytes:
    """The contents of ``path``, a regular file within the size limit; raises :class:`InputFileError` or ``OSError``."""
    _check_stat(os.stat(path), path, text, max_bytes)
    cap = limit(text) if max_bytes is None else max_bytes
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        _check_stat(os.fstat(fd), path, text, max_bytes)  # the file opened is the file checked
        chunks, total = [], 0
        while total <= cap:
            chunk = os.read(fd, min(1 << 20, cap + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    finally:
        os.close(fd)
    if total > cap:
        env = TEXT_ENV if text else DATA_ENV
        raise InputFileError(errno.EFBIG, f"it grew past the {cap}-byte limit while being read (set {env} to "
                                          "raise it)", path)
    return b"".join(chunks)


def read_text(path: str | os.PathLike, encoding: str = "utf-8", errors: str = "strict") -> str:
    """:func:`read_bytes` with the text limit, decoded."""
    return read_bytes(path, text=True).decode(encoding, errors)


def describe(error: OSError, path: str | os.PathLike | None = None) -> str:
    """One line for an ``OSError`` reading an input, naming the file."""
    where = path if path is not None else error.filename
    reason = error.strerror or str(error)
    return f"{where}: {reason}" if where is not None else reason


__all__ = ["DATA_LIMIT", "TEXT_LIMIT", "InputFileError", "check_file", "describe", "limit", "read_bytes", "read_text"]
