"""Light maps (Mühlbacher §4.3, Eq 4.1): per-object RGB irradiance E in the object's UV chart.

A light map stores E (W m⁻²-like, the integral of incident radiance × cos θ)
at texel centres ``((i + ½)/S, (j + ½)/S)`` of the chart ``uv / uv_repeat``
(row 0 at v = 0), one float EXR per object (``object_000.exr`` …, by the
object's index in the scene).  Renderers shade the diffuse part as
``ρ_d · E(uv)`` — the thesis's ``k_d/π · E``, since the models' ρ_d is the
diffuse BRDF value — and look E up bilinearly with clamp-to-edge (what
``GL_LINEAR`` with ``GL_CLAMP_TO_EDGE`` does), so ``cpu`` and ``gl`` agree.

The texels' surface points come from the shapes' own parameterisations
(plane, sphere, cylinder: as :func:`sbrdf_lib.surface.tessellate` builds
them) or, for meshes, by rasterising the triangles in the chart; texels no
triangle covers are filled from their neighbours (:func:`dilate`), so
bilinear look-ups at chart borders do not fetch black.  A mesh's UVs must be
a chart (:func:`mesh_chart`); a mesh whose file has none gets one generated
(``uv_layout: chart``, the default under ``lightmap:``: each triangle its own
atlas place, :func:`sbrdf_lib.surface.triangle_atlas`).
"""

from __future__ import annotations

import os

import numpy as np

from sbrdf_core.errors import SbrdfError

__all__ = ["chart_uv", "diffuse_glsl", "diffuse_value", "dilate", "has_diffuse", "load_maps", "lookup", "map_path",
           "mesh_chart", "texels"]


def has_diffuse(model) -> bool:
    """Whether a model declares a Lambertian term the light maps can shade: ``rho_d`` (f = ρ_d) or ``k_d`` (k_d/π)."""
    names = {p.name for p in model.parameters}
    return "rho_d" in names or "k_d" in names


def diffuse_value(params: dict) -> np.ndarray:
    """The diffuse BRDF value of unpacked parameters: ρ_d, or k_d/π (Mühlbacher's k_d is an albedo, Eq 4.1)."""
    if "rho_d" in params:
        return np.asarray(params["rho_d"], np.float64)
    return np.asarray(params["k_d"], np.float64) / np.pi


def diffuse_glsl(exprs: dict) -> str | None:
    """GLSL of the diffuse BRDF value from a model's parameter expressions (None without a diffuse term)."""
    if "rho_d" in exprs:
        return exprs["rho_d"]
    if "k_d" in exprs:
        return f"({exprs['k_d']} / 3.14159265358979)"
    return None


def map_path(directory: str, index: int) -> str:
    """The light map of object ``index``."""
    return os.path.join(directory, f"object_{index:03d}.exr")


def chart_uv(obj, uv: np.ndarray) -> np.ndarray:
    """Chart coordinates of a shape's texture coordinates (which carry ``uv_repeat``)."""
    return np.asarray(uv, np.float64) / np.asarray(obj.uv_repeat, np.float64)


def texel_centres(size: int) -> np.ndarray:
    """``(S, S, 2)`` chart coordinates (u, v) of the texel centres; row j is v."""
    c = (np.arange(size) + 0.5) / size
    v, u = np.meshgrid(c, c, indexing="ij")
    return np.stack([u, v], -1)


def texels(obj, size: int, mesh=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World positions ``(S, S, 3)``, unit normals ``(S, S, 3)`` and coverage ``(S, S)`` of an object's texels."""
    uv = texel_centres(size).reshape(-1, 2)
    u, v = uv[:, 0], uv[:, 1]
    p = obj.params
    valid = np.ones(len(uv), bool)
    if obj.shape == "plane":
        sx, sy = p["size"]
        pos = np.stack([(u - 0.5) * sx, (v - 0.5) * sy, np.zeros_like(u)], 1)
        nrm = np.tile([0.0, 0.0, 1.0], (len(u), 1))
    elif obj.shape == "sphere":
        phi, theta = 2 * np.pi * u, np.pi * (1 - v)
        nrm = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
        pos = p["radius"] * nrm
    elif obj.shape == "cylinder":
        phi = 2 * np.pi * u
        nrm = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(u)], 1)
        pos = np.concatenate([p["radius"] * nrm[:, :2], ((v - 0.5) * p["height"])[:, None]], 1)
    else:
        if mesh is None:
            raise SbrdfError("lightmap: a mesh object needs its tessellation")
        pos, nrm, valid = _rasterise(mesh, mesh_chart(mesh, obj), size)
        return pos, nrm, valid
    m = obj.matrix
    lin = m[:3, :3]
    pos = pos @ lin.T + m[:3, 3]
    nrm = nrm @ np.linalg.inv(lin)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    S = size
    return pos.reshape(S, S, 3), nrm.reshape(S, S, 3), valid.reshape(S, S)


def mesh_chart(mesh, obj) -> np.ndarray:
    """Per-vertex chart coordinates of a mesh: its UVs, which must be a chart (inside [0, 1], no overlap).

    Overlap is detected by area: the triangles' total UV area must not exceed the square's.  A mesh file without
    UVs has a generated chart here (``uv_layout: chart``); a file's own UVs that are not a chart are refused
    (the renderers read one UV set, the material's).
    """
    uv = chart_uv(obj, mesh.uvs)
    tri = uv[mesh.indices.astype(np.int64)]
    area = 0.5 * np.abs((tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1])
                        - (tri[:, 2, 0] - tri[:, 0, 0]) * (tri[:, 1, 1] - tri[:, 0, 1]))
    if (tri < -1e-9).any() or (tri > 1 + 1e-9).any() or area.sum() > 1 + 1e-6:
        raise SbrdfError(f"lightmap: mesh {obj.params.get('file')}: its UVs (divided by uv_repeat) are not a chart "
                         "(outside [0, 1] or overlapping); give the mesh non-overlapping UVs for its light map, or none (a chart "
                         "is then generated)")
    return uv


def _rasterise(mesh, chart: np.ndarray, size: int):
    """Texel positions and normals of a mesh by rasterising its triangles in the chart."""
    S = size
    idx = mesh.indices.astype(np.int64)
    T = len(idx)
    tri_uv = chart[idx]
    pos = np.zeros((S * S, 3))
    nrm = np.zeros((S * S, 3))
    valid = np.zeros(S * S, bool)
    P, N = mesh.positions[idx], mesh.normals[idx]
    for t in range(T):
        a, b, c = tri_uv[t] * S - 0.5  # texel-centre coordinates
        lo = np.maximum(np.floor(np.minimum(np.minimum(a, b), c)).astype(int), 0)
        hi = np.minimum(np.ceil(np.maximum(np.maximum(a, b), c)).astype(int), S - 1)
        if (hi < lo).any():
            continue
        ys, xs = np.mgrid[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
        q = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)
        d = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
        if abs(d) < 1e-15:
            continue
        l0 = ((b[1] - c[1]) * (q[:, 0] - c[0]) + (c[0] - b[0]) * (q[:, 1] - c[1])) / d
        l1 = ((c[1] - a[1]) * (q[:, 0] - c[0]) + (a[0] - c[0]) * (q[:, 1] - c[1])) / d
        lam = np.stack([l0, l1, 1 - l0 - l1], 1)
        ok = (lam >= -1e-9).all(1)
        k = (q[ok, 1] * S + q[ok, 0]).astype(np.int64)
        pos[k] = lam[ok] @ P[t]
        nrm[k] = lam[ok] @ N[t]
        valid[k] = True
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    return pos.reshape(S, S, 3), nrm.reshape(S, S, 3), valid.reshape(S, S)


def dilate(E: np.ndarray, valid: np.ndarray, passes: int = 4) -> np.ndarray:
    """Fill uncovered texels with the mean of their covered 8-neighbours, ``passes`` rings deep (then 0)."""
    E = np.where(valid[..., None], E, 0.0)
    have = valid.copy()
    for _ in range(passes):
        if have.all():
            break
        acc = np.zeros_like(E)
        cnt = np.zeros(have.shape)
        pad_e = np.pad(E, ((1, 1), (1, 1), (0, 0)))
        pad_h = np.pad(have, 1)
        H, W = have.shape
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy == dx == 0:
                    continue
                h = pad_h[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
                acc += pad_e[1 + dy:1 + dy + H, 1 + dx:1 + dx + W] * h[..., None]
                cnt += h
        fill = ~have & (cnt > 0)
        E[fill] = acc[fill] / cnt[fill][:, None]
        have = have | fill
    return E


def lookup(E: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear clamp-to-edge look-up of a map ``(S, S, 3)`` at chart coordinates ``(R, 2)`` -> ``(R, 3)``."""
    S1, S0 = E.shape[:2]
    x = np.clip(uv[:, 0] * S0 - 0.5, 0, S0 - 1)
    y = np.clip(uv[:, 1] * S1 - 0.5, 0, S1 - 1)
    i0, j0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    i1, j1 = np.minimum(i0 + 1, S0 - 1), np.minimum(j0 + 1, S1 - 1)
    fx, fy = (x - i0)[:, None], (y - j0)[:, None]
    m = E.astype(np.float64)
    return (1 - fy) * ((1 - fx) * m[j0, i0] + fx * m[j0, i1]) + fy * ((1 - fx) * m[j1, i0] + fx * m[j1, i1])


def load_maps(scene) -> dict[int, np.ndarray]:
    """Every object's map ``(S, S, 3)`` float32; an error naming the missing file and how to bake it."""
    from sbrdf_core.io import read_exr

    out = {}
    for k in range(len(scene.objects)):
        path = map_path(scene.lightmap.directory, k)
        if not os.path.isfile(path):
            raise SbrdfError(f"{scene.file}: lightmap: {path} does not exist; bake the light maps first (a "
                             "LightmapBake node, or `python -m sbrdf_lightmap SCENE`), or set lightmap: {use: false}")
        E = np.asarray(read_exr(path), np.float32)[..., :3]
        if E.ndim != 3 or not np.all(np.isfinite(E)):
            raise SbrdfError(f"{path}: a light map must be a finite RGB image, got shape {E.shape}")
        out[k] = E
    return out
