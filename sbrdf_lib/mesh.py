"""Triangle meshes from files: OBJ, PLY and glTF 2.0 (``.gltf``, ``.glb``).

:func:`load_mesh` is the one entry point: renderers tessellate with it and
the scene loader checks files and sizes a mesh's bounding sphere with it
(:func:`mesh_vertex_radius`), so a file is parsed by the same rules everywhere.

- OBJ keeps the project's own reader (:func:`read_obj`, :func:`load_obj`):
  it needs no dependency, names the line of a malformed statement, and splits
  corners with distinct ``v/vt/vn`` in first-use order, which renders of
  existing scenes depend on bit for bit.  ``trimesh`` (5.2) was measured on
  tests/plugins/test_render.py's two quads meeting at a mirrored UV seam: with
  ``process=False, maintain_order=True`` it merged the seam's split corners
  (6 vertices instead of 8) and dropped the UVs; with ``process=False`` alone
  it keeps the 8 corners but reorders the triangles of polygons (every
  polygon's first triangle, then every second one), which changes which hit
  wins a depth tie; and its errors do not name a line.  So it does not
  replace this reader.
- PLY and glTF go through ``trimesh`` (the ``mesh`` extra: pure Python on
  numpy).  glTF ``NORMAL``, ``TEXCOORD_0`` and ``TANGENT`` are read raw
  (trimesh reads UVs only for primitives with a material and does not keep
  tangents), node transforms are applied, and the texture coordinates are
  turned to the OBJ/OpenGL convention ``v ← 1 − v``; a glTF tangent's
  handedness ``w`` then already means what sbrdf's does (``B = w · N × T``
  points along +v), as the glTF spec's MikkTSpace tangents are made for
  that convention.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import NamedTuple

import numpy as np

from sbrdf_core import input_files
from sbrdf_core.errors import SbrdfError

__all__ = ["FORMATS", "MeshData", "load_mesh", "load_obj", "mesh_files", "mesh_vertex_radius", "read_obj"]

#: File suffixes :func:`load_mesh` reads, with the format's name.
FORMATS = {".obj": "OBJ", ".ply": "PLY", ".gltf": "glTF", ".glb": "glTF binary (GLB)"}


def read_obj(path: str) -> tuple[list[list[float]], list[list[float]], list[list[float]], dict[tuple[int, ...], int],
                                 list[list[int]]]:
    """The raw ``v``, ``vt``, ``vn`` lists, the corner table ``{(v, vt, vn): index}`` and triangle corner ids.

    Polygons are fanned into triangles; a malformed line raises :class:`SbrdfError` naming its line.
    """
    v: list[list[float]] = []
    vt: list[list[float]] = []
    vn: list[list[float]] = []
    corners: dict[tuple[int, ...], int] = {}  # (v, vt, vn) indices, -1 where absent -> corner id
    faces: list[list[int]] = []  # three corner ids per triangle
    try:
        lines = input_files.read_bytes(path).decode("utf-8").splitlines()
    except OSError as e:
        raise SbrdfError(f"{path}: cannot read mesh: {e.strerror}") from None
    for lineno, line in enumerate(lines, 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        try:
            if parts[0] == "v":
                v.append([float(x) for x in parts[1:4]])
            elif parts[0] == "vt":
                vt.append([float(x) for x in parts[1:3]])
            elif parts[0] == "vn":
                vn.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                ids = []
                for c in parts[1:]:
                    fields = (c.split("/") + ["", ""])[:3]
                    key = tuple(_obj_index(f, n) if f else -1 for f, n in zip(fields, (len(v), len(vt), len(vn))))
                    ids.append(corners.setdefault(key, len(corners)))
                if len(ids) < 3:
                    raise ValueError("a face needs at least 3 vertices")
                faces.extend([ids[0], ids[k], ids[k + 1]] for k in range(1, len(ids) - 1))
        except (ValueError, IndexError) as e:
            raise SbrdfError(f"{path}:{lineno}: malformed OBJ line {line.strip()!r}: {e}") from None
    return v, vt, vn, corners, faces


def load_obj(path: str) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray]:
    """Positions, uvs, normals (each per corner-vertex, ``None`` if absent) and triangle indices of an OBJ file.

    Corners with distinct ``v/vt/vn`` triples become distinct vertices, as a GPU needs them.
    """
    v, vt, vn, corners, faces = read_obj(path)
    if not faces:
        raise SbrdfError(f"{path}: the mesh has no faces")
    keys = np.array(list(corners), dtype=np.int64)
    if (keys[:, 0] < 0).any() or keys[:, 0].max() >= len(v):
        raise SbrdfError(f"{path}: a face refers to a vertex that does not exist")
    pos = np.asarray(v, float)[keys[:, 0]]
    uv = np.asarray(vt, float)[keys[:, 1]] if vt and (keys[:, 1] >= 0).all() else None
    nrm = np.asarray(vn, float)[keys[:, 2]] if vn and (keys[:, 2] >= 0).all() else None
    return pos, uv, nrm, np.asarray(faces, dtype=np.uint32)


def mesh_files(path: str) -> list[str]:
    """The files a mesh is read from: the file itself and a ``.gltf``'s external buffers (for cache keys)."""
    out = [str(path)]
    if Path(path).suffix.lower() == ".gltf":
        import json

        try:
            header = json.loads(input_files.read_bytes(path, text=True))
            uris = [b.get("uri", "") for b in header.get("buffers", [])]
        except (OSError, ValueError, AttributeError, TypeError):
            return out
        out += [str(Path(path).parent / u) for u in uris if isinstance(u, str) and u and ":" not in u]
    return out


def mesh_vertex_radius(path: str) -> float:
    """Largest distance of a mesh's vertices from its origin: its bounding sphere.

    An unreadable or malformed file gives 1: the scene check and the renderer
    that load it (:func:`load_mesh`) report the error.
    """
    try:
        v = load_mesh(path).positions
    except (SbrdfError, ImportError):
        return 1.0
    return float(np.sqrt((v**2).sum(axis=1)).max()) if len(v) else 1.0


class MeshData(NamedTuple):
    """A mesh file's triangles in its object space, per corner-vertex (as a GPU needs them).

    ``uvs``, ``normals`` and ``tangents`` (xyz + handedness w = ±1) are ``None``
    where the file has none.  The arrays are read-only (they are cached).
    """

    positions: np.ndarray  # (N, 3) float64
    uvs: np.ndarray | None  # (N, 2)
    normals: np.ndarray | None  # (N, 3)
    tangents: np.ndarray | None  # (N, 4)
    indices: np.ndarray  # (M, 3) uint32


def load_mesh(path: str) -> MeshData:
    """The triangles of an OBJ, PLY, glTF or GLB file (by suffix), cached while the file is unchanged.

    Raises :class:`SbrdfError` naming the file (and for OBJ the line) when it
    cannot be read, is not in its format, or has no triangles; an unknown
    suffix is an error naming the formats read.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise SbrdfError(f"{path}: unsupported mesh format {suffix or '(no suffix)'!r}; "
                         f"supported: {', '.join(FORMATS)}")
    try:
        st = Path(path).stat()
        input_files.check_file(path)  # a device or FIFO would be read forever, a huge file whole
    except OSError as e:
        raise SbrdfError(f"{path}: cannot read mesh: {e.strerror}") from None
    stamps: list[tuple[int, int] | None] = [(st.st_mtime_ns, st.st_size)]  # None: a buffer that cannot be stat'ed
    for f in mesh_files(path)[1:]:  # a .gltf's buffers: the cache follows them too
        try:
            input_files.check_file(f)
        except OSError as e:
            if not isinstance(e, input_files.InputFileError):
                stamps.append(None)
                continue
            raise SbrdfError(f"{f}: cannot read the buffer of mesh {path}: {e.strerror}") from None
        try:
            s = Path(f).stat()
            stamps.append((s.st_mtime_ns, s.st_size))
        except OSError:
            stamps.append(None)
    return _load_cached(str(path), suffix, tuple(stamps))


@functools.lru_cache(maxsize=16)
def _load_cached(path: str, suffix: str, stamps: tuple) -> MeshData:
    if suffix == ".obj":
        try:
            pos, uv, nrm, idx = load_obj(path)
        except UnicodeDecodeError as e:
            raise SbrdfError(f"{path}: not a UTF-8 OBJ file (byte 0x{e.object[e.start]:02x} at offset {e.start})") from None
        data = MeshData(pos, uv, nrm, None, idx)
    else:
        data = _load_trimesh(path, suffix)
    if not len(data.indices):
        raise SbrdfError(f"{path}: the mesh has no faces")
    n = len(data.positions)
    if data.indices.max() >= n:
        raise SbrdfError(f"{path}: a face refers to a vertex that does not exist")
    for name, a in zip(data._fields, data):
        if a is not None and not np.isfinite(a).all():
            raise SbrdfError(f"{path}: the mesh's {name} are not all finite")
        if a is not None:
            a.setflags(write=False)
    return data


def _load_trimesh(path: str, suffix: str) -> MeshData:
    from sbrdf_core.extras import require

    trimesh = require("trimesh", extra="mesh", feature=f"reading {FORMATS[suffix]} meshes")
    try:
        if suffix == ".ply":
            return _ply(trimesh, path)
        return _gltf(trimesh, path, suffix)
    except SbrdfError:
        raise
    except Exception as e:  # trimesh raises whatever its parsers meet: ValueError, KeyError, struct.error, ...
        raise SbrdfError(f"{path}: not a readable {FORMATS[suffix]} file: {type(e).__name__}: {e}") from None


def _ply(trimesh, path: str) -> MeshData:
    m = trimesh.load(path, file_type="ply", force="mesh", process=False)
    pos = np.asarray(m.vertices, dtype=np.float64)
    if not len(pos) or not len(m.faces):
        raise SbrdfError(f"{path}: the mesh has no faces (a PLY point cloud?)")
    raw = m.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    names = raw.dtype.names if raw is not None and getattr(raw, "dtype", None) is not None else ()
    nrm = np.stack([raw[k] for k in ("nx", "ny", "nz")], 1).astype(np.float64) if {"nx", "ny", "nz"} <= set(names) else None
    uv = getattr(m.visual, "uv", None)
    uv = np.asarray(uv, dtype=np.float64) if uv is not None and np.shape(uv) == (len(pos), 2) else None
    if nrm is not None and len(nrm) != len(pos):
        nrm = None
    return MeshData(pos, uv, nrm, None, np.asarray(m.faces, dtype=np.uint32).reshape(-1, 3))


_RAW = {"NORMAL": "_SBRDF_NORMAL", "TEXCOORD_0": "_SBRDF_TEXCOORD_0", "TANGENT": "_SBRDF_TANGENT"}


def _gltf(trimesh, path: str, suffix: str) -> MeshData:
    """glTF through trimesh, with the raw NORMAL, TEXCOORD_0 and TANGENT accessors kept as custom attributes."""
    import io
    import json
    import struct

    data = input_files.read_bytes(path)
    chunks = []
    if suffix == ".glb":
        if data[:4] != b"glTF":
            raise SbrdfError(f"{path}: not a GLB file (no 'glTF' magic)")
        if len(data) < 20:
            raise SbrdfError(f"{path}: a truncated GLB file ({len(data)} bytes)")
        offset = 12
        while offset + 8 <= len(data):
            length, kind = struct.unpack_from("<II", data, offset)
            chunks.append([kind, data[offset + 8:offset + 8 + length]])
            offset += 8 + length
        if not chunks or chunks[0][0] != 0x4E4F534A:
            raise SbrdfError(f"{path}: a GLB file's first chunk must be its JSON")
        text = chunks[0][1]
    else:
        text = data
    header = json.loads(text)
    if not isinstance(header, dict) or not header.get("meshes"):
        raise SbrdfError(f"{path}: the glTF file has no meshes")
    for m in header["meshes"]:
        for p in m.get("primitives", []):
            attrs = p.get("attributes", {})
            attrs.update({alias: attrs[k] for k, alias in _RAW.items() if k in attrs})
    text = json.dumps(header).encode()
    if suffix == ".glb":
        text += b" " * (-len(text) % 4)
        chunks[0][1] = text
        body = b"".join(struct.pack("<II", len(c), k) + c for k, c in chunks)
        blob = struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body
        scene = trimesh.load(io.BytesIO(blob), file_type="glb", force="scene", process=False, skip_materials=True)
    else:
        resolver = trimesh.resolvers.FilePathResolver(str(Path(path).resolve()))
        scene = trimesh.load(io.BytesIO(text), file_type="gltf", force="scene", process=False, resolver=resolver,
                             skip_materials=True)
    parts = []
    for node in scene.graph.nodes_geometry:
        matrix, name = scene.graph[node]
        g = scene.geometry[name]
        if not hasattr(g, "faces") or not len(g.faces):
            continue  # points and lines
        parts.append(_gltf_part(g, np.asarray(matrix, dtype=np.float64)))
    if not parts:
        raise SbrdfError(f"{path}: the glTF file has no triangles")
    keys = ("uvs", "normals", "tangents")
    out: dict[str, list[np.ndarray | None]] = {k: [] for k in keys}  # None: the primitive lacks it
    positions: list[np.ndarray] = []
    indices: list[np.ndarray] = []
    base = 0
    for part in parts:
        for k in keys:  # an attribute only some primitives have is dropped: it would be undefined elsewhere
            out[k].append(part[k])
        positions.append(part["positions"])
        indices.append(part["indices"] + base)
        base += len(part["positions"])
    cat = {k: _concatenate_all(out[k]) for k in keys}
    return MeshData(np.concatenate(positions), cat["uvs"], cat["normals"], cat["tangents"],
                    np.concatenate(indices).astype(np.uint32))


def _concatenate_all(arrays: list[np.ndarray | None]) -> np.ndarray | None:
    """The arrays end to end, or ``None`` when any of them is missing."""
    present = [a for a in arrays if a is not None]
    return np.concatenate(present) if len(present) == len(arrays) else None


def _gltf_part(g, matrix: np.ndarray) -> dict:
    attrs = getattr(g, "vertex_attributes", {}) or {}
    n = len(g.vertices)

    def raw(key, width):
        a = attrs.get(_RAW[key])
        a = None if a is None else np.asarray(a, dtype=np.float64).reshape(n, -1)
        return a if a is not None and a.shape[1] == width else None

    lin = matrix[:3, :3]
    det = np.linalg.det(lin)
    pos = np.asarray(g.vertices, dtype=np.float64) @ lin.T + matrix[:3, 3]
    idx = np.asarray(g.faces, dtype=np.int64).reshape(-1, 3)
    if det < 0:  # a mirroring node: glTF reverses the winding (and the frame's handedness)
        idx = idx[:, ::-1]
    nrm, uv, tan = raw("NORMAL", 3), raw("TEXCOORD_0", 2), raw("TANGENT", 4)
    if nrm is not None:
        nrm = nrm @ np.linalg.inv(lin)
    if uv is not None:
        uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)  # glTF's origin is the image's top left
    if tan is not None:
        w = np.where(tan[:, 3] < 0, -1.0, 1.0) * (1.0 if det >= 0 else -1.0)
        tan = np.concatenate([tan[:, :3] @ lin.T, w[:, None]], axis=1)
    return {"positions": pos, "indices": idx, "normals": nrm, "uvs": uv, "tangents": tan}


def _obj_index(field: str, count: int) -> int:
    i = int(field)
    return i - 1 if i > 0 else count + i  # OBJ is 1-based; negative indices count back from the end
