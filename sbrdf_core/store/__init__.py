"""How an artifact lives in zarr: layout, chunking, attributes, completion, integrity, the store's lock.

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
which :func:`check_artifact` checks a cached artifact before reuse.

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

The package's modules are private; this one re-exports their public names
and imports each module the first time one of its names is asked for, so
``from sbrdf_core.store import join`` (graph validation, node kinds) loads
neither zarr nor fsspec:

``_layout``
    names, paths, chunk keys, :class:`ArrayLayout`, confinement (no zarr);
``_digests``
    a chunk's crc32c, a side file's sha256, the chunk files present;
``_shards``
    direct reads and writes of zarr shard files, bypassing zarr where it is safe;
``_artifact``
    :class:`Artifact`, :func:`open_artifact`, :class:`ArtifactWriter`, :func:`write_chunk`;
``_integrity``
    :func:`check_artifact`, :func:`repair` and the store's lock (:class:`StoreLock`, :class:`S3Lease`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ._artifact import Artifact, ArtifactWriter, CheckedArray, members, open_artifact, write_chunk
    from ._digests import chunk_crc, file_digest
    from ._integrity import (
        HOLDER_FILE,
        LOCK_FILE,
        Damage,
        S3Lease,
        StoreBusy,
        StoreLock,
        artifact_dirs,
        check_artifact,
        drop_chunks,
        repair,
        stray_entries,
    )
    from ._layout import (
        ARTIFACT_MARKER,
        MARKERS,
        NODE_NAME,
        ArrayLayout,
        ChunkError,
        chunk_key,
        disk_errors,
        inside_store,
        join,
        pose_major_chunks,
        texel_tile,
    )

#: Public name -> the private module that defines it.
_WHERE = {
    **dict.fromkeys(("ARTIFACT_MARKER", "MARKERS", "NODE_NAME", "ArrayLayout", "ChunkError", "chunk_key", "disk_errors",
                     "inside_store", "join", "pose_major_chunks", "texel_tile"), "_layout"),
    **dict.fromkeys(("chunk_crc", "file_digest"), "_digests"),
    **dict.fromkeys(("Artifact", "ArtifactWriter", "CheckedArray", "members", "open_artifact", "write_chunk"), "_artifact"),
    **dict.fromkeys(("HOLDER_FILE", "LOCK_FILE", "Damage", "S3Lease", "StoreBusy", "StoreLock", "artifact_dirs",
                     "check_artifact", "drop_chunks", "repair", "stray_entries"), "_integrity"),
}

#: The same names as ``_WHERE``'s (tests/core/test_store.py checks).
__all__ = [
    "ARTIFACT_MARKER", "ArrayLayout", "Artifact", "ArtifactWriter", "CheckedArray", "ChunkError", "Damage",
    "HOLDER_FILE", "LOCK_FILE", "MARKERS", "NODE_NAME", "S3Lease", "StoreBusy", "StoreLock", "artifact_dirs",
    "check_artifact", "chunk_crc", "chunk_key", "disk_errors", "drop_chunks", "file_digest", "inside_store", "join",
    "members", "open_artifact", "pose_major_chunks", "repair", "stray_entries", "texel_tile", "write_chunk",
]


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # once: later lookups do not come back here
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
