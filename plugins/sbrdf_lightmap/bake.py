"""The light-map bake: per-object irradiance E from point, directional and area lights and an environment,
direct plus a stated number of diffuse bounces (Mühlbacher §4.3; his maps came from an offline photon mapper).

For each texel's surface point p with normal n (:func:`sbrdf_lib.lightmap.texels`):

- point light: E = I (n·l)⁺ / d² (or I (n·l)⁺ without fall-off), directional: E = E_l (n·l)⁺, each times its
  visibility (a shadow ray, :func:`sbrdf_lib.surface.cast`);
- area light (a rectangle of radiance L_e, one-sided): E = Σ_k L_e (n·ω_k)⁺ (n_e·−ω_k)⁺ / d_k² · A / K over K
  stratified points, each with a shadow ray;
- environment and bounces share K cosine-distributed hemisphere rays per texel (pdf cos θ/π, so
  E ≈ π/K Σ L(ω_k)): a ray that leaves the scene sees the environment (direct); one that hits a surface's front
  sees its diffuse radiance ρ_d·E_{b−1} from the previous bounce's maps, looked up at the hit (bounce b).
  Each bounce's map is tent-filtered ``smooth`` times (indirect light is smooth, its noise is not).

The total E = direct + Σ bounces.  Radiance follows the models' convention that ρ_d is the diffuse BRDF value
(lambert: f_r = ρ_d), so a physically plausible diffuse surface has ρ_d ≤ 1/π.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_lib.lightmap import chart_uv, diffuse_value, dilate, has_diffuse, lookup, texels
from sbrdf_lib.surface import cast, tessellate

logger = logging.getLogger(__name__)

__all__ = ["bake", "cosine_rays", "rho_d"]


def _frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ref = np.where((np.abs(n[:, 2]) < 0.9)[:, None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    t = np.cross(ref, n)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def cosine_rays(n: np.ndarray, K: int, rng) -> np.ndarray:
    """``(R, K, 3)`` cosine-distributed directions about unit normals ``(R, 3)``, stratified per texel."""
    R = len(n)
    side = int(np.ceil(np.sqrt(K)))
    cells = np.arange(K)
    u = ((cells % side)[None] + rng.random((R, K))) / side
    v = ((cells // side)[None] + rng.random((R, K))) / int(np.ceil(K / side))
    r, phi = np.sqrt(u), 2 * np.pi * v
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1 - u, 0))], -1)
    t, b = _frame(n)
    return local[..., :1] * t[:, None] + local[..., 1:2] * b[:, None] + local[..., 2:] * n[:, None]


def rho_d(material, uv: np.ndarray) -> np.ndarray:
    """A material's diffuse BRDF value (ρ_d, or k_d/π) ``(R, 3)`` at texture coordinates."""
    if material.surface is not None or not has_diffuse(material.model):
        raise SbrdfError(f"lightmap: material {material.name!r} has no rho_d or k_d (light maps shade k_d/pi E, "
                         "Eq 4.1)")
    return np.broadcast_to(diffuse_value(material.model.unpack(material.lookup(uv))), (len(uv), 3))


def _visible(scene, materials, meshes, origin, dirs, dist) -> np.ndarray:
    hits, _ = cast(scene, materials, dirs, origin, meshes)
    return hits.t >= dist * (1 - 1e-6)


def bake(scene, materials: dict, environment=None, size: int | None = None, bounces: int | None = None,
         samples: int | None = None, seed: int | None = None) -> tuple[dict[int, np.ndarray], dict]:
    """Every object's light map ``(S, S, 3)`` float32 and statistics; settings default to the scene's ``lightmap:``.

    ``environment``: an object with ``radiance(dirs (R, 3)) -> (R, 3)`` (the environment scene effect), or None.
    """
    lm = scene.lightmap
    S = size if size is not None else lm.size
    B = bounces if bounces is not None else lm.bounces
    K = samples if samples is not None else lm.samples
    rng = np.random.default_rng(seed if seed is not None else lm.seed)
    areas = lm.area_lights if lm is not None else []
    t0 = time.perf_counter()
    meshes: dict = {}
    for k, obj in enumerate(scene.objects):
        meshes[k] = tessellate(obj)
    pos, nrm, cover = {}, {}, {}
    for k, obj in enumerate(scene.objects):
        p, n, v = texels(obj, S, meshes[k])
        pos[k], nrm[k], cover[k] = p.reshape(-1, 3), n.reshape(-1, 3), v.reshape(-1)
    scale = max(1.0, max(float(np.abs(p).max()) for p in pos.values()))
    eps = 1e-6 * scale * 10
    direct, rays = {}, {}
    for k in range(len(scene.objects)):
        p, n = pos[k], nrm[k]
        o = p + eps * n
        E = np.zeros((len(p), 3))
        for light in scene.lights:
            if light.type == "point":
                d = light.vector - p
                dist = np.linalg.norm(d, axis=1)
                w = d / np.maximum(dist, 1e-300)[:, None]
                irr = light.power[None] / (dist ** 2 if light.falloff else np.ones_like(dist))[:, None]
            else:
                w = np.broadcast_to(light.vector, p.shape).copy()
                dist = np.full(len(p), np.inf)
                irr = np.broadcast_to(light.power, p.shape)
            c = np.einsum("ij,ij->i", n, w)
            lit = c > 0
            if lit.any():
                vis = _visible(scene, materials, meshes, o[lit], w[lit], dist[lit])
                E[lit] += irr[lit] * (c[lit] * vis)[:, None]
        for a in areas:
            E += _area(scene, materials, meshes, a, p, n, o, K, rng)
        direct[k] = E
        if B == 0 and environment is None:
            continue
        # the hemisphere rays: environment now, bounces later
        dirs = cosine_rays(n, K, rng)
        flat = dirs.reshape(-1, 3)
        hits, which = cast(scene, materials, flat, np.repeat(o, K, axis=0), meshes)
        front = np.einsum("ij,ij->i", hits.normal, flat) < 0
        which = np.where((which >= 0) & ~front, -2, which)  # the back of a surface: unlit (-2)
        if environment is not None:
            miss = which == -1
            Lenv = np.zeros((len(flat), 3))
            if miss.any():
                Lenv[miss] = environment.radiance(flat[miss])
            E += np.pi / K * Lenv.reshape(len(p), K, 3).sum(1)
        rays[k] = (hits, which)
    total = {k: direct[k].copy() for k in direct}
    prev = {k: _as_map(direct[k], cover[k], S) for k in direct}
    for _ in range(B):
        nxt = {}
        for k in range(len(scene.objects)):
            hits, which = rays[k]
            L = np.zeros((len(which), 3))
            for j, obj in enumerate(scene.objects):
                sel = np.nonzero(which == j)[0]
                if sel.size == 0:
                    continue
                uv = hits.uv[sel]
                L[sel] = rho_d(materials[obj.material], uv) * lookup(prev[j], chart_uv(obj, uv))
            E = _smooth(_as_map(np.pi / K * L.reshape(-1, K, 3).sum(1), cover[k], S), cover[k].reshape(S, S),
                        lm.smooth if lm is not None else 0)
            total[k] += E.reshape(-1, 3)
            nxt[k] = E
        prev = nxt
    maps = {k: _as_map(total[k], cover[k], S).astype(np.float32) for k in total}
    stats = {"bake_s": time.perf_counter() - t0, "size": S, "bounces": B, "samples": K,
             "texels": int(sum(c.sum() for c in cover.values()))}
    logger.info("light maps of %s: %d objects, %d², %d bounce(s), %d samples: %.1f s", scene.file,
                len(maps), S, B, K, stats["bake_s"])
    return maps, stats


def _smooth(E: np.ndarray, cover: np.ndarray, passes: int) -> np.ndarray:
    """``passes`` 3×3 tent filters over the covered texels of a map (weights renormalised at chart borders)."""
    H, W = cover.shape
    w = cover.astype(np.float64)
    for _ in range(passes):
        acc, tot = np.zeros_like(E), np.zeros_like(w)
        pe, pw = np.pad(E * w[..., None], ((1, 1), (1, 1), (0, 0))), np.pad(w, 1)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                k = (2 - abs(dy)) * (2 - abs(dx))
                acc += k * pe[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
                tot += k * pw[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
        E = np.where(cover[..., None], acc / np.maximum(tot, 1e-300)[..., None], E)
    return E


def _as_map(E: np.ndarray, cover: np.ndarray, S: int) -> np.ndarray:
    return dilate(E.reshape(S, S, 3), cover.reshape(S, S))


def _area(scene, materials, meshes, a: dict, p, n, o, K: int, rng) -> np.ndarray:
    """Irradiance from one rectangular emitter, K stratified points per texel, with shadow rays."""
    m = a["matrix"]
    sx, sy = a["size"]
    side = int(np.ceil(np.sqrt(K)))
    cells = np.arange(K)
    u = ((cells % side)[None] + rng.random((len(p), K))) / side - 0.5
    v = ((cells // side)[None] + rng.random((len(p), K))) / int(np.ceil(K / side)) - 0.5
    local = np.stack([u * sx, v * sy, np.zeros_like(u)], -1)
    q = local @ m[:3, :3].T + m[:3, 3]  # (R, K, 3)
    ne = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
    d = q - p[:, None]
    dist = np.linalg.norm(d, axis=-1)
    w = d / np.maximum(dist, 1e-300)[..., None]
    c = np.einsum("rkc,rc->rk", w, n)
    ce = -(w @ ne)
    ok = (c > 0) & (ce > 0)
    g = np.where(ok, c * ce / np.maximum(dist ** 2, 1e-300), 0.0)
    if ok.any():
        idx = np.nonzero(ok.reshape(-1))[0]
        vis = _visible(scene, materials, meshes, np.repeat(o, K, axis=0)[idx], w.reshape(-1, 3)[idx],
                       dist.reshape(-1)[idx] * (1 - 1e-4))
        g.reshape(-1)[idx] *= vis
    return a["radiance"][None] * (g.sum(1) * sx * sy / K)[:, None]
