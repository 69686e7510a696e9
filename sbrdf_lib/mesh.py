"""Triangle meshes from OBJ files: the one OBJ reader of sbrdf.

Renderers tessellate with :func:`load_obj` (corner-vertices as a GPU needs
them); the scene loader sizes a mesh's bounding sphere with
:func:`obj_vertex_radius`.  Both read the file through :func:`read_obj`, so a
file is parsed by the same rules everywhere.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from sbrdf_core.errors import SbrdfError

__all__ = ["load_obj", "obj_vertex_radius", "read_obj"]


def read_obj(path: str) -> tuple[list, list, list, dict, list]:
    """The raw ``v``, ``vt``, ``vn`` lists, the corner table ``{(v, vt, vn): index}`` and triangle corner ids.

    Polygons are fanned into triangles; a malformed line raises :class:`SbrdfError` naming its line.
    """
    v, vt, vn, corners, faces = [], [], [], {}, []
    try:
        lines = Path(path).read_text().splitlines()
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


@functools.lru_cache(maxsize=64)
def obj_vertex_radius(path: str) -> float:
    """Largest distance of an OBJ file's ``v`` vertices from its origin: a mesh's bounding sphere.

    An unreadable, malformed or vertex-less file gives 1: the renderer that
    loads it (:func:`load_obj`) reports the error with its line.
    """
    try:
        v = np.asarray(read_obj(path)[0], dtype=float)
    except (SbrdfError, UnicodeDecodeError, ValueError):
        return 1.0
    return float(np.sqrt((v**2).sum(axis=1)).max()) if v.ndim == 2 and len(v) else 1.0


def _obj_index(field: str, count: int) -> int:
    i = int(field)
    return i - 1 if i > 0 else count + i  # OBJ is 1-based; negative indices count back from the end
