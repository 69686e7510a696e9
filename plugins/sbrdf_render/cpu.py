"""cpu: the NumPy reference renderer (ray casting; any BRDF-model plugin through its ``eval``).

For every sample a ray through it finds the nearest surface
(analytic planes, spheres and cylinders, triangle meshes), the material's
parameters are looked up at the hit's texture coordinates, and the radiance
is seed 000 Eq 6.3 with point and directional lights:

    L(ω_r) = Σ_l f_r(ω_l → ω_r) · E_l · (N · ω_l),   E_l = I_l / d_l² (fall-off) or I_l.

Antialiasing (the scene's ``antialias: n²``, 4 unless it says) supersamples:
every pixel is n×n rays through a stratified sub-pixel grid (centres at
((a + ½)/n, (b + ½)/n) of the pixel), i.e. the image is cast at n times the
resolution and n×n blocks are averaged in linear radiance
(:meth:`~sbrdf_lib.scene.Scene.supersampled`, :func:`~sbrdf_lib.scene.downsample`).
``gl`` rasterises the same points, so the two still agree pixel for pixel.
``antialias: 1`` casts one ray through each pixel centre.

A scene with ``lightmap:`` shades diffuse as ρ_d·E(uv) from its baked maps
(:func:`lightmap_radiance`, seed 004 Eq 4.1) and the lights add f_r − ρ_d.

``filter: trilinear`` materials with MIP levels choose their level from the
texel footprint between neighbouring rays of the grid cast (:func:`lods`).

It is the ground truth the ``gl`` renderer is tested against: float64, exact
intersections, shadow rays (only when the scene asks for shadows), and the
same per-pixel tangent frames and parameter lookups as the GPU.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from sbrdf_core import contracts
from sbrdf_core.types import RenderResult
from sbrdf_lib.scene import downsample
from sbrdf_lib.surface import Hits, cast, local_frame

from . import materials as mat
from .base import SceneRenderer
from .effects import active_effects, check_covered

__all__ = ["BATCH", "CPURenderer", "cast", "check_lightmapped", "lightmap_radiance", "lods", "occluded", "render_scene", "shade",
           "texel_edges"]

logger = logging.getLogger(__name__)

#: Pixels shaded per BRDF evaluation: bounds the temporaries of multi-lobe models at 1080p.
BATCH = 1 << 16


def occluded(scene, materials, points: np.ndarray, to_light: np.ndarray, distance: np.ndarray, meshes: dict) -> np.ndarray:
    """Whether anything opaque lies between each point and its light (shadow rays, offset off the surface)."""
    start = points + 1e-6 * max(1.0, float(np.abs(points).max(initial=1.0))) * to_light
    hits, _ = cast(scene, materials, to_light, start, meshes)
    return hits.t < distance * (1 - 1e-6)


def shade(material: mat.SceneMaterial, lights, hits: Hits, view_dirs: np.ndarray, shadow=None,
          lod: np.ndarray | None = None, diffuse: bool = True) -> np.ndarray:
    """Radiance ``(R, 3)`` of hit points under point and directional lights (Eq 6.3).

    ``lod``: each hit's MIP level of detail (trilinear materials, :func:`lods`).  ``diffuse=False``: the lights
    add f_r − ρ_d only (a light-mapped scene's diffuse comes from its maps, :func:`lightmap_radiance`).
    """
    model = material.model
    two_sided = bool(contracts.optional(model, "two_sided", "brdf-model"))  # transmissive: lit from either side, |N·ω_l|
    out = np.zeros((len(view_dirs), 3))
    for s in range(0, len(view_dirs), BATCH):
        sl = slice(s, s + BATCH)
        t, b, n = local_frame(hits.normal[sl], hits.tangent[sl])
        params = (model.unpack(material.lookup(hits.uv[sl], None if lod is None else lod[sl]))
                  if material.surface is None else {})
        wo = -view_dirs[sl]
        wo_local = np.stack([np.einsum("ij,ij->i", t, wo), np.einsum("ij,ij->i", b, wo), np.einsum("ij,ij->i", n, wo)], 1)
        for k, light in enumerate(lights):
            if light.type == "point":
                d = light.vector - hits.position[sl]
                dist = np.linalg.norm(d, axis=1)
                wi = d / np.maximum(dist, 1e-300)[:, None]
                E = np.broadcast_to(light.power, wi.shape) / (dist**2 if light.falloff else np.ones_like(dist))[:, None]
            else:
                wi = np.broadcast_to(light.vector, hits.position[sl].shape)
                dist = np.full(len(wi), np.inf)
                E = np.broadcast_to(light.power, wi.shape)
            cos = np.einsum("ij,ij->i", n, wi)
            lit = cos != 0 if two_sided else cos > 0
            if shadow is not None:
                lit &= ~shadow(k, hits.position[sl], wi, dist)
            if not lit.any():
                continue
            wi_local = np.stack([np.einsum("ij,ij->i", t, wi), np.einsum("ij,ij->i", b, wi), cos], 1)
            idx = np.arange(s, min(s + BATCH, len(view_dirs)))[lit]
            if material.surface is not None:  # its own shading rule (shading maps): radiance from E directly
                out[idx] += material.surface.radiance(hits.uv[sl][lit], wi_local[lit], wo_local[lit], E[lit])
                continue
            f = model.eval({k2: v[lit] for k2, v in params.items()}, wi_local[lit][:, None], wo_local[lit][:, None])[:, 0]
            if not diffuse:
                from sbrdf_lib.lightmap import diffuse_value

                front = (wi_local[lit][:, 2] > 0) & (wo_local[lit][:, 2] > 0)  # where the Lambertian term exists
                f = f - diffuse_value(params)[lit] * front[:, None]
            out[idx] += f * E[lit] * np.abs(cos[lit])[:, None]
    return out


def lightmap_radiance(scene, materials: dict, maps: dict, hits: Hits, which: np.ndarray) -> np.ndarray:
    """ρ_d · E(uv) of light-mapped hits (Mühlbacher Eq 4.1, ρ_d = k_d/π), ``(R, 3)``; 0 on misses."""
    from sbrdf_lib.lightmap import chart_uv, diffuse_value, lookup

    out = np.zeros((len(which), 3))
    for k, obj in enumerate(scene.objects):
        sel = np.nonzero(which == k)[0]
        if sel.size == 0:
            continue
        m = materials[obj.material]
        uv = hits.uv[sel]
        rho_d = diffuse_value(m.model.unpack(m.lookup(uv)))
        out[sel] = rho_d * lookup(maps[k], chart_uv(obj, uv))
    return out


def check_lightmapped(scene, materials: dict) -> None:
    """A light-mapped scene's materials need a diffuse term (ρ_d or k_d) and a model rather than a shading rule."""
    from sbrdf_core.errors import SbrdfError
    from sbrdf_lib.lightmap import has_diffuse

    for name in sorted({o.material for o in scene.objects}):
        m = materials[name]
        if m.surface is not None or not has_diffuse(m.model):
            raise SbrdfError(f"{scene.file}: lightmap: material {name!r} has no rho_d or k_d; light maps shade "
                             "k_d/pi E (Eq 4.1) with the model's diffuse term")


def lods(scene, materials: dict, hits: Hits, which: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Per cast sample, the MIP level of detail of its material's lookup (0 where not trilinear).

    The footprint is the texel distance to the neighbouring samples on the same object, in the grid the
    renderer casts (the supersampled one, as ``gl`` rasterises it): :func:`materials.lod`.
    """
    out = np.zeros(len(which))
    for k, obj in enumerate(scene.objects):
        m = materials[obj.material]
        if not m.trilinear:
            continue
        valid = (which == k).reshape(shape)
        if not valid.any():
            continue
        V, U = m.maps.shape[:2]
        uv = np.where(valid.reshape(-1, 1), hits.uv, 0.0).reshape(*shape, 2)
        out[valid.reshape(-1)] = mat.lod(uv, valid, (U, V))[valid]
    return out


def render_scene(scene, materials: dict, meshes: dict | None = None, effects: list | None = None,
                 registry=None) -> tuple[np.ndarray, dict]:
    """The scene's linear image ``(H, W, 3)`` float64, and timings; ``materials`` from :func:`materials.resolve`.

    ``effects``: the scene effects to add (default: those the scene wants, :func:`effects.active_effects`).
    With ``scene.antialias`` = n² > 1 the scene is cast at n times its resolution (effects see that
    scene and its sample indices) and n×n blocks are averaged.
    """
    t0 = time.perf_counter()
    n = scene.subpixels
    scene = scene.supersampled()
    if effects is None:
        effects = active_effects(scene, materials, registry)
    check_covered(scene, effects)
    meshes = {} if meshes is None else meshes
    dirs, origin = scene.camera.rays()
    H, W = dirs.shape[:2]
    dirs = dirs.reshape(-1, 3)
    hits, which = cast(scene, materials, dirs, origin, meshes)
    t_cast = time.perf_counter() - t0
    image = np.tile(scene.background, (len(dirs), 1)).astype(np.float64)
    shadow = None
    if scene.shadows:
        def shadow(k, points, wi, dist):
            return occluded(scene, materials, points, wi, dist, meshes)
    lod_all = lods(scene, materials, hits, which, (H, W)) if any(m.trilinear for m in materials.values()) else None
    lit_maps = scene.lightmapped
    if lit_maps:
        from sbrdf_lib.lightmap import load_maps

        check_lightmapped(scene, materials)
        diffuse = lightmap_radiance(scene, materials, load_maps(scene), hits, which)
    for name, material in materials.items():
        ks = [k for k, o in enumerate(scene.objects) if o.material == name]
        sel = np.nonzero(np.isin(which, ks))[0]
        if sel.size == 0:
            continue
        sub = Hits(hits.t[sel], hits.position[sel], hits.normal[sel], hits.tangent[sel], hits.uv[sel])
        lod = None
        if material.trilinear:
            assert lod_all is not None, "computed when any material is trilinear"
            lod = lod_all[sel]
        image[sel] = shade(material, scene.lights, sub, dirs[sel], shadow, lod, diffuse=not lit_maps)
        if lit_maps:
            image[sel] += diffuse[sel]
        for effect in effects:  # environment lighting, mirrors: only what the scene wants
            image[sel] += effect.cpu_radiance(material, sub, dirs[sel], sel)
    image = downsample(image.reshape(H, W, 3), n)
    hit = (which.reshape(H // n, n, W // n, n) >= 0).any(axis=(1, 3))  # pixels any of whose samples hit
    stats = {"cast_s": t_cast, "total_s": time.perf_counter() - t0, "pixels_hit": int(hit.sum()), "antialias": n * n}
    return image, stats


def texel_edges(scene, materials: dict, n: int = 8, meshes: dict | None = None) -> np.ndarray:
    """``(H, W)`` bool: the pixels a texel edge crosses, found with an n×n grid of rays per pixel.

    A pixel is on a texel edge when all its rays hit the same object and the texel of that object's
    material they land in (``floor(uv · (U, V))``, repeating) is not the same for all of them:
    where point sampling picks one texel for a pixel that shows several.  Silhouettes (rays on
    different objects or missing) are not counted.
    """
    import dataclasses

    W, H = scene.camera.resolution
    fine = dataclasses.replace(scene, antialias=n * n).supersampled()
    dirs, origin = fine.camera.rays()
    hits, which = cast(fine, materials, dirs.reshape(-1, 3), origin, meshes)
    texel = np.full(len(which), -1, np.int64)
    for k, obj in enumerate(scene.objects):
        sel = which == k
        maps = materials[obj.material].maps
        V, U = maps.shape[:2] if maps is not None else (1, 1)
        i = np.floor(hits.uv[sel, 0] * U).astype(np.int64) % U
        j = np.floor(hits.uv[sel, 1] * V).astype(np.int64) % V
        texel[sel] = j * U + i
    obj_blocks, tex_blocks = which.reshape(H, n, W, n), texel.reshape(H, n, W, n)
    one_object = (obj_blocks >= 0).all(axis=(1, 3)) & (obj_blocks == obj_blocks[:, :1, :, :1]).all(axis=(1, 3))
    return one_object & (tex_blocks != tex_blocks[:, :1, :, :1]).any(axis=(1, 3))


class CPURenderer(SceneRenderer):
    """``Render`` plugin ``cpu``: one scene file, rendered by :func:`render_scene`."""

    def render(self, material, prepared: dict | None = None) -> RenderResult:
        scene, materials = self.load(material, prepared)
        image, stats = render_scene(scene, materials, registry=self.registry)
        logger.info("cpu render of %s: %.2f s", self.scene_path, stats["total_s"])
        return self.result(scene, image, stats)
