"""Surface frames and shapes: triangles for the GPU, exact ray hits for the CPU reference.

Every surface point carries a position, a unit normal, a tangent with
handedness ``(T, w)`` and texture coordinates.  The bitangent is rebuilt per
pixel as ``B = w · N × T`` after Gram–Schmidt, so mirrored UV charts shade
correctly (seed 000 Eq 6.1 and the notes' correction: the sign of the UV
determinant is the handedness).

Built-in shapes, in object space (+z up, centred at the origin):

- ``plane``: z = 0, u along +x, v along +y.
- ``sphere``: u = φ / 2π around +z from +x, v = 1 − θ/π (v = 1 at the north pole).
- ``cylinder``: around +z, u = φ / 2π, v = z / height + ½, open ends.
- ``mesh``: an OBJ, PLY, glTF or GLB file (:func:`sbrdf_lib.mesh.load_mesh`); its tangents (glTF ``TANGENT``)
  where the file has them and normals too, else :func:`vertex_frames` from its uvs.

The CPU renderer intersects the built-in shapes analytically and meshes with
barycentric interpolation of the same vertex attributes the GPU interpolates
(:func:`cast`).  Scene effects shade ray hits (:class:`Hits`) in the frame
:func:`local_frame` builds, so they agree with the renderers by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sbrdf_core.errors import SbrdfError

from .mesh import load_mesh

__all__ = ["ATLAS_MARGIN", "EPS", "Hits", "Mesh", "cast", "intersect", "intersect_mesh", "local_frame", "tessellate",
           "triangle_atlas", "unit", "vertex_frames"]

EPS = 1e-7


@dataclass
class Mesh:
    """World-space triangles; per vertex position, normal, tangent (xyz + handedness) and uv."""

    positions: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3)
    tangents: np.ndarray  # (N, 4)
    uvs: np.ndarray  # (N, 2)
    indices: np.ndarray  # (M, 3) uint32

    @property
    def triangles(self) -> int:
        return len(self.indices)


@dataclass
class Hits:
    """Surface attributes at ray hits; ``t = inf`` where a ray missed."""

    t: np.ndarray  # (R,)
    position: np.ndarray  # (R, 3)
    normal: np.ndarray  # (R, 3)
    tangent: np.ndarray  # (R, 4)
    uv: np.ndarray  # (R, 2)

    @classmethod
    def empty(cls, n: int) -> Hits:
        return cls(np.full(n, np.inf), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 4)), np.zeros((n, 2)))

    def take(self, other: Hits, mask: np.ndarray) -> None:
        for name in ("t", "position", "normal", "tangent", "uv"):
            getattr(self, name)[mask] = getattr(other, name)[mask]


def vertex_frames(pos: np.ndarray, uv: np.ndarray, idx: np.ndarray, normals: np.ndarray | None = None):
    """Per-vertex normals (area-weighted, unless given) and tangents with handedness (Eq 6.1, corrected)."""
    p0, p1, p2 = pos[idx[:, 0]], pos[idx[:, 1]], pos[idx[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    face_n = np.cross(e1, e2)  # length = 2 × area: area weighting for free
    if normals is None:
        normals = np.zeros_like(pos)
        for k in range(3):
            np.add.at(normals, idx[:, k], face_n)
    normals = unit(normals, fallback=(0.0, 0.0, 1.0))
    d1, d2 = uv[idx[:, 1]] - uv[idx[:, 0]], uv[idx[:, 2]] - uv[idx[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    r = np.where(np.abs(det) > 1e-20, 1.0 / np.where(det == 0, 1.0, det), 0.0)[:, None]
    dp_ds = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * r  # ∂P/∂s
    dp_dt = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * r  # ∂P/∂t
    weight = np.linalg.norm(face_n, axis=1, keepdims=True)
    t_acc, b_acc = np.zeros_like(pos), np.zeros_like(pos)
    for k in range(3):
        np.add.at(t_acc, idx[:, k], unit(dp_ds) * weight)
        np.add.at(b_acc, idx[:, k], unit(dp_dt) * weight)
    t = t_acc - normals * np.einsum("ij,ij->i", t_acc, normals)[:, None]
    # Degenerate uv (no ∂P/∂s): any unit vector perpendicular to the normal.
    alt = np.cross(normals, np.where(np.abs(normals[:, 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]))
    bad = np.linalg.norm(t, axis=1) < 1e-12
    t[bad] = alt[bad]
    t = unit(t)
    w = np.where(np.einsum("ij,ij->i", np.cross(normals, t), b_acc) < 0, -1.0, 1.0)
    return normals, np.concatenate([t, w[:, None]], axis=1)


def unit(v: np.ndarray, fallback=None) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    out = v / np.where(n > 0, n, 1.0)
    if fallback is not None:
        out[n[..., 0] == 0] = fallback
    return out


# -- tessellation (GPU) ------------------------------------------------------------------------------------------------


def tessellate(obj) -> Mesh:
    """World-space triangles of a :class:`~sbrdf_lib.scene.SceneObject`."""
    p = obj.params
    pos: np.ndarray
    idx: np.ndarray
    uv: np.ndarray | None  # None (a mesh file without UVs) until projected
    nrm: np.ndarray | None  # None (a mesh file without normals) until computed
    tan: np.ndarray | None
    if obj.shape == "plane":
        sx, sy = p["size"]
        s, t = (a.ravel() for a in np.meshgrid([0.0, 1.0], [0.0, 1.0]))
        pos = np.stack([(s - 0.5) * sx, (t - 0.5) * sy, np.zeros(4)], axis=1)
        nrm = np.tile([0.0, 0.0, 1.0], (4, 1))
        tan = np.tile([1.0, 0.0, 0.0, 1.0], (4, 1))
        uv = np.stack([s, t], axis=1)
        idx = np.array([[0, 1, 3], [0, 3, 2]], dtype=np.uint32)
    elif obj.shape in ("sphere", "cylinder"):
        nu, nv = p["segments"] if obj.shape == "sphere" else (p["segments"], 1)
        s, t = (a.ravel() for a in np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1)))
        phi = 2 * np.pi * s
        ring = np.stack([np.cos(phi), np.sin(phi)], axis=1)
        if obj.shape == "sphere":
            theta = np.pi * (1 - t)
            nrm = np.concatenate([ring * np.sin(theta)[:, None], np.cos(theta)[:, None]], axis=1)
            pos = p["radius"] * nrm
        else:
            nrm = np.concatenate([ring, np.zeros((len(s), 1))], axis=1)
            pos = np.concatenate([p["radius"] * ring, ((t - 0.5) * p["height"])[:, None]], axis=1)
        tan = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi), np.ones_like(phi)], axis=1)
        uv = np.stack([s, t], axis=1)
        a = (np.arange(nv)[:, None] * (nu + 1) + np.arange(nu)[None, :]).ravel()
        idx = np.concatenate([np.stack([a, a + 1, a + nu + 2], 1), np.stack([a, a + nu + 2, a + nu + 1], 1)]).astype(np.uint32)
    elif obj.shape == "mesh":
        pos, uv, nrm, tan, idx = load_mesh(p["file"])
        if uv is None:  # planar projection onto the mesh's xy bounding box
            lo, hi = pos[:, :2].min(0), pos[:, :2].max(0)
            uv = (pos[:, :2] - lo) / np.where(hi > lo, hi - lo, 1.0)
            if p.get("uv_layout", "planar") == "chart":  # a light map needs a chart: one atlas cell per triangle pair
                nrm, _ = vertex_frames(pos, uv, idx, nrm)  # smooth normals from the shared vertices, then split them
                corners = np.asarray(idx, np.int64).ravel()
                pos, nrm, tan = pos[corners], nrm[corners], None
                uv = triangle_atlas(len(idx))
                idx = np.arange(len(corners), dtype=np.uint32).reshape(-1, 3)
        if tan is None or nrm is None:  # glTF: tangents are meaningful only with the normals they were made for
            nrm, tan = vertex_frames(pos, uv, idx, nrm)
        else:
            nrm = unit(nrm, fallback=(0.0, 0.0, 1.0))
            t = tan[:, :3] - nrm * np.einsum("ij,ij->i", tan[:, :3], nrm)[:, None]  # Gram–Schmidt, as the shaders do
            tan = np.concatenate([unit(t, fallback=(1.0, 0.0, 0.0)), tan[:, 3:]], axis=1)
    else:  # pragma: no cover - the scene validator rejects unknown shapes
        raise SbrdfError(f"unknown shape {obj.shape!r}")
    return _to_world(obj, pos, nrm, tan, uv, idx)


#: Inset of a generated chart's triangles in their atlas cell (fraction of the cell): keeps texels of neighbours apart.
ATLAS_MARGIN = 0.1


def triangle_atlas(n: int, margin: float = ATLAS_MARGIN) -> np.ndarray:
    """Per-corner texture coordinates ``(3n, 2)`` giving each of ``n`` triangles its own place in [0, 1]².

    Triangles go in pairs into the cells of a g × g grid (g = ⌈√⌈n/2⌉⌉), one below and one above the cell's
    diagonal, each inset by ``margin`` of the cell and both counter-clockwise: a chart without overlap, as a
    light map needs, for meshes whose file has no UVs.  Shapes are not kept (each triangle is mapped affinely
    onto its half cell), so texel density follows the triangle count, not the area.
    """
    g = max(1, int(np.ceil(np.sqrt(np.ceil(n / 2)))))
    m = margin
    lower = np.array([[m, m], [1 - 2 * m, m], [m, 1 - 2 * m]])
    upper = np.array([[1 - m, 1 - m], [2 * m, 1 - m], [1 - m, 2 * m]])
    k = np.arange(n)
    cell = np.stack([(k // 2) % g, (k // 2) // g], axis=1).astype(np.float64)
    local = np.where((k % 2 == 0)[:, None, None], lower[None], upper[None])
    return ((cell[:, None, :] + local) / g).reshape(-1, 2)


def _to_world(obj, pos, nrm, tan, uv, idx) -> Mesh:
    m = obj.matrix
    lin = m[:3, :3]
    normal_m = np.linalg.inv(lin).T
    return Mesh(pos @ lin.T + m[:3, 3], unit(nrm @ normal_m.T), np.concatenate([unit(tan[:, :3] @ lin.T), tan[:, 3:]], 1),
                uv * np.asarray(obj.uv_repeat), np.array(idx, dtype=np.uint32))


# -- ray intersection (CPU reference) --------------------------------------------------------------------------------


def intersect(obj, origin: np.ndarray, dirs: np.ndarray, mesh: Mesh | None = None) -> list[Hits]:
    """Ray hits with one object, nearest first: ``[front]`` or ``[front, back]`` for closed quadrics.

    ``origin (3,)`` or ``(R, 3)``, ``dirs (R, 3)`` in world space.  Meshes need their tessellated ``mesh``.
    """
    if obj.shape == "mesh":
        assert mesh is not None, "a mesh object is intersected through its tessellated mesh"
        return [intersect_mesh(mesh, origin, dirs)]
    inv = np.linalg.inv(obj.matrix)
    o = np.broadcast_to(origin, dirs.shape) @ inv[:3, :3].T + inv[:3, 3]
    d = dirs @ inv[:3, :3].T  # not renormalised: t stays the world-space ray parameter
    p = obj.params
    out = []
    if obj.shape == "plane":
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[:, 2] / d[:, 2]
        ts = [t]
    else:
        a2 = d[:, 0] ** 2 + d[:, 1] ** 2 + (d[:, 2] ** 2 if obj.shape == "sphere" else 0)
        b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1] + (o[:, 2] * d[:, 2] if obj.shape == "sphere" else 0)
        c = o[:, 0] ** 2 + o[:, 1] ** 2 + (o[:, 2] ** 2 if obj.shape == "sphere" else 0) - p["radius"] ** 2
        disc = b * b - a2 * c
        root = np.sqrt(np.where(disc >= 0, disc, np.nan))
        with np.errstate(divide="ignore", invalid="ignore"):
            ts = [(-b - root) / a2, (-b + root) / a2]
    for t in ts:
        x = o + np.nan_to_num(t, nan=0.0, posinf=0.0, neginf=0.0)[:, None] * d
        ok = np.isfinite(t) & (t > EPS)
        if obj.shape == "plane":
            sx, sy = p["size"]
            ok &= (np.abs(x[:, 0]) <= sx / 2) & (np.abs(x[:, 1]) <= sy / 2)
            nrm = np.tile([0.0, 0.0, 1.0], (len(t), 1))
            tan = np.tile([1.0, 0.0, 0.0, 1.0], (len(t), 1))
            uv = np.stack([x[:, 0] / sx + 0.5, x[:, 1] / sy + 0.5], axis=1)
        else:
            phi = np.mod(np.arctan2(x[:, 1], x[:, 0]), 2 * np.pi)
            tan = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi), np.ones_like(phi)], axis=1)
            if obj.shape == "sphere":
                nrm = x / p["radius"]
                uv = np.stack([phi / (2 * np.pi), 1 - np.arccos(np.clip(nrm[:, 2], -1, 1)) / np.pi], axis=1)
            else:
                ok &= np.abs(x[:, 2]) <= p["height"] / 2
                nrm = np.stack([x[:, 0], x[:, 1], np.zeros_like(phi)], axis=1) / p["radius"]
                uv = np.stack([phi / (2 * np.pi), x[:, 2] / p["height"] + 0.5], axis=1)
        hits = Hits.empty(len(t))
        world = _to_world(obj, x, nrm, tan, uv, np.zeros((0, 3)))
        hits.take(Hits(np.where(ok, t, np.inf), world.positions, world.normals, world.tangents, world.uvs), ok)
        out.append(hits)
    return out


def intersect_mesh(mesh: Mesh, origin: np.ndarray, dirs: np.ndarray, clusters: int = 256) -> Hits:
    """Nearest ray–triangle hits (Möller–Trumbore), culled by the bounding boxes of spatial triangle clusters.

    Triangles are sorted along the mesh's longest axis into clusters; a ray is
    tested only against clusters whose box it enters.  This is a reference,
    exact to float64, not a fast ray tracer.
    """
    R = len(dirs)
    origin = np.broadcast_to(origin, dirs.shape)
    P, I = mesh.positions, mesh.indices.astype(np.int64)
    centroid = P[I].mean(axis=1)
    order = np.argsort(centroid[:, int(np.argmax(np.ptp(centroid, axis=0)))], kind="stable")
    best_t = np.full(R, np.inf)
    best_tri = np.full(R, -1)
    best_uv = np.zeros((R, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_d = 1.0 / dirs
    for start in range(0, len(order), clusters):
        tri = order[start:start + clusters]
        pts = P[I[tri]].reshape(-1, 3)
        lo, hi = pts.min(0) - 1e-9, pts.max(0) + 1e-9
        with np.errstate(invalid="ignore"):
            t0, t1 = (lo - origin) * inv_d, (hi - origin) * inv_d
            near = np.nanmax(np.minimum(t0, t1), axis=1)
            far = np.nanmin(np.maximum(t0, t1), axis=1)
        rays = np.nonzero((far >= np.maximum(near, 0)) & (near < best_t))[0]
        if rays.size == 0:
            continue
        a, b, c = P[I[tri, 0]], P[I[tri, 1]], P[I[tri, 2]]
        e1, e2 = b - a, c - a
        d = dirs[rays][:, None, :]
        o = origin[rays][:, None, :]
        pvec = np.cross(d, e2[None])
        det = np.einsum("rtk,tk->rt", pvec, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            s = o - a[None]
            u = np.einsum("rtk,rtk->rt", s, pvec) * inv
            q = np.cross(s, e1[None])
            v = np.einsum("rtk,rtk->rt", d, q) * inv
            t = np.einsum("rtk,tk->rt", q, e2) * inv
        ok = (np.abs(det) > 1e-14) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > EPS)
        t = np.where(ok, t, np.inf)
        k = np.argmin(t, axis=1)
        tk = t[np.arange(len(rays)), k]
        better = tk < best_t[rays]
        r = rays[better]
        best_t[r] = tk[better]
        best_tri[r] = tri[k[better]]
        best_uv[r] = np.stack([u[np.arange(len(rays)), k], v[np.arange(len(rays)), k]], 1)[better]
    hits = Hits.empty(R)
    hit = best_tri >= 0
    if hit.any():
        f = I[best_tri[hit]]
        w1, w2 = best_uv[hit, 0:1], best_uv[hit, 1:2]
        w0 = 1 - w1 - w2

        def lerp(attr):
            return w0 * attr[f[:, 0]] + w1 * attr[f[:, 1]] + w2 * attr[f[:, 2]]

        hits.t[hit] = best_t[hit]
        hits.position[hit] = lerp(P)
        hits.normal[hit] = unit(lerp(mesh.normals))
        hits.tangent[hit, :3] = lerp(mesh.tangents[:, :3])
        hits.tangent[hit, 3] = np.sign(lerp(mesh.tangents[:, 3:4])[:, 0] + 1e-300)
        hits.uv[hit] = lerp(mesh.uvs)
    return hits


def local_frame(normal: np.ndarray, tangent: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel orthonormal (T, B, N): Gram–Schmidt of T against N, B = w · N × T."""
    n = unit(normal)
    t = tangent[:, :3] - n * np.einsum("ij,ij->i", tangent[:, :3], n)[:, None]
    t = unit(t)
    return t, np.cross(n, t) * tangent[:, 3:4], n


def cast(scene, materials, dirs: np.ndarray, origin: np.ndarray, meshes: dict | None = None):
    """Nearest alpha-surviving hit per ray, and the index of its object (−1 for a miss).

    ``materials``: name -> a scene material with ``alpha`` and ``alive(uv)``; ``meshes`` caches tessellations.
    """
    meshes = meshes if meshes is not None else {}
    best = Hits.empty(len(dirs))
    which = np.full(len(dirs), -1)
    for k, obj in enumerate(scene.objects):
        mesh = meshes.get(k)
        if obj.shape == "mesh" and mesh is None:
            mesh = meshes[k] = tessellate(obj)
        m = materials[obj.material]
        for hits in intersect(obj, origin, dirs, mesh):
            hit = np.isfinite(hits.t) & (hits.t < best.t)
            if m.alpha is not None and hit.any():
                idx = np.nonzero(hit)[0]
                hit[idx[~m.alive(hits.uv[idx])]] = False
            best.take(hits, hit)
            which[hit] = k
    return best, which
