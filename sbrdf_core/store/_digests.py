"""Digests that prove a stored chunk or side file is what was written.

A chunk's done marker holds the crc32c of its values (:func:`chunk_crc`); a
side file is recorded by size and sha256 (:func:`file_digest`);
:func:`written` lists the chunk files that exist and can hold their checksum.
"""

from __future__ import annotations

import hashlib

import numpy as np

from ._layout import _CHUNK_KEY, ArrayLayout, join


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
