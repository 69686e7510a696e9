"""The ``mirror`` scene effect: planar reflectors (Mühlbacher §4.5) for plane objects with ``reflector: true``.

Any number of planes may be reflectors, each with a material of its own;
each gets one mirror pass per frame.  Options come from the scene's
``mirror:`` section (:data:`sbrdf_envmap.MIRROR_PARAMS`).

``gl`` (real time): every frame, for each reflector, the scene *without*
that plane is drawn from the camera mirrored about the plane (geometry
behind the plane clipped) into a buffer of radiance, world position and
normal, diffuse-only as in the thesis (ρ_d × the point and directional
lights, no shadows, plus ρ_d·D(N) of the environment when the scene has
one; other reflectors are drawn diffuse too: no recursion); where no
geometry is seen, the buffer holds the environment.  The radiance gets a MIP
chain.  Each specular sample direction ω_i of the plane's material is
projected into that buffer: intersect the ray (P, ω_i) with the tangent
plane stored at the pixel's own mirror look-up, project the hit with the
mirror camera, then once more with the tangent plane found there (the
refinement step; ``refinements`` sets how often).  A ray that finds no
geometry projects to its vanishing point (the environment's direction).  A
pixel's filter level comes from the lobe's four extreme directions
projected the same way (ellipse area / samples, log₄), once per pixel.  The
samples are the deterministic patterns and estimator of :mod:`.sampling`.

``cpu`` (the reference): Monte Carlo over the same lobes with real ray
casting: the radiance of the first object hit, diffuse-only by the same
definition, or the environment where the ray leaves the scene.  Both add
the *specular* reflection (f_r − ρ_d); the plane's own diffuse lighting is
the renderer's (lights) and the environment effect's (ρ_d·D(N): for a
reflector's material it adds only that, the mirror effect its specular).

Limits: alpha masks are ignored in the mirror pass; the reflected scene is
diffuse (view-dependent materials look diffuse in a mirror, §1).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_core.params import Param
from sbrdf_lib.lightmap import diffuse_value, has_diffuse

from . import MIRROR_PARAMS, cubemap, lobes, sampling
from .effect import EnvironmentEffect, _frame_from_normal, mc_lobes

logger = logging.getLogger(__name__)


def reflector_indices(scene) -> list[int]:
    """Indices of the scene's planes with ``reflector: true``."""
    return [k for k, o in enumerate(scene.objects) if o.shape == "plane" and o.params.get("reflector")]


def reflector_materials(scene) -> set[str]:
    """Materials of the reflectors: their specular lobes are the mirror effect's."""
    return {scene.objects[k].material for k in reflector_indices(scene)}


@dataclasses.dataclass
class Reflector:
    """One planar reflector: its object index, material, plane (point, normal towards the camera), the rest."""

    index: int
    material: str
    plane: tuple[np.ndarray, np.ndarray]
    others: Any  # the scene without this plane
    gl: Any = None  # its MirrorPass


def exclusive_materials(scene, idx, shared, elsewhere) -> list[str]:
    """Problems if the objects ``idx`` do not each have a material of their own: the effect renders per material.

    ``shared(j, k, material)`` words two of them sharing one, ``elsewhere(material, k)`` another object using it.
    """
    out = []
    owner: dict[str, int] = {}
    for k in idx:
        m = scene.objects[k].material
        if m in owner:
            out.append(shared(owner[m], k, m))
        owner.setdefault(m, k)
    out += [elsewhere(o.material, k) for k, o in enumerate(scene.objects) if o.material in owner and k not in idx]
    return out


class MirrorEffect:
    name = "mirror"

    params: tuple[Param, ...] = MIRROR_PARAMS  # a subclass may declare fewer (cube maps: no refinements)

    def __init__(self, *, samples: int = 7, estimator: str = "4.25", xi_border: float = sampling.XI_BORDER,
                 ring_radius: float = sampling.RING_RADIUS, line_threshold: float = 4.0, refinements: int = 1,
                 mc_samples: int = 64, seed: int = 0):
        self.samples, self.estimator, self.xi_border = samples, estimator, xi_border
        self.ring_radius, self.line_threshold, self.refinements = ring_radius, line_threshold, refinements
        self.mc_samples, self.seed = mc_samples, seed
        self.reflectors: list[Reflector] = []
        self.env: EnvironmentEffect | None = None
        self.maps: dict | None = None

    @staticmethod
    def wanted(scene) -> bool:
        return bool(reflector_indices(scene)) or scene.section("mirror") is not None

    @staticmethod
    def options(scene) -> dict:
        return dict(vars(scene.section("mirror"))) if scene.section("mirror") is not None else {}

    @staticmethod
    def check(scene) -> list[str]:
        """The scene-level conditions of :meth:`prepare`, checked when the graph is validated."""
        idx = reflector_indices(scene)
        if not idx:
            return ["mirror: options are given but no plane has reflector: true"]
        return exclusive_materials(
            scene, idx,
            lambda j, k, m: (f"reflector: true planes {j} and {k} share material {m!r}: one reflector: true plane "
                             "is supported per material (give each reflector a material of its own)"),
            lambda m, k: (f"the reflector's material {m!r} must not be used by other objects (object {k}; give the "
                          "plane a material of its own)"))

    def prepare(self, scene, materials=None, gl_context=None) -> None:
        problems = self.check(scene)
        if problems:
            raise SbrdfError(f"{scene.file}: {problems[0]}")
        self._prepare_common(scene, materials, gl_context)
        self.reflectors = []
        for k in reflector_indices(scene):
            obj = scene.objects[k]
            p0 = obj.matrix[:3, 3]
            n = obj.matrix[:3, :3] @ np.array([0.0, 0.0, 1.0])
            n /= np.linalg.norm(n)
            if np.dot(n, scene.camera.position - p0) < 0:
                n = -n
            others = dataclasses.replace(scene, objects=tuple(o for j, o in enumerate(scene.objects) if j != k))
            self.reflectors.append(Reflector(k, obj.material, (p0, n), others))
        self.by_material = {r.material: r for r in self.reflectors}

    def _prepare_common(self, scene, materials, gl_context) -> None:
        """What the reflected (or cube-mapped) scene needs: light maps, or the environment's D(N) and map."""
        self.scene, self.materials = scene, materials or {}
        self.maps = None
        if getattr(scene, "lightmapped", False):
            from sbrdf_lib.lightmap import load_maps

            self.maps = load_maps(scene)
        env = scene.section("environment")
        self.env = None
        if env is not None:  # what the reflected scene needs of it: D(N) and the map itself
            opts = dict(getattr(env, "options", None) or {})
            self.env = EnvironmentEffect(method="sampling", **{k: opts[k] for k in ("size", "diffuse_size", "prefilter")
                                                               if k in opts})
            self.env.prepare(scene, materials, gl_context)

    # -- compatibility with the single-reflector attributes ------------------------------------------------------

    @property
    def index(self) -> int:
        return self.reflectors[0].index

    @property
    def material(self) -> str:
        return self.reflectors[0].material

    @property
    def plane(self):
        return self.reflectors[0].plane

    @property
    def others(self):
        return self.reflectors[0].others

    @property
    def _gl(self):
        return self.reflectors[0].gl if self.reflectors else None

    # -- cpu: Monte Carlo with ray casting --------------------------------------------------------------------------

    def diffuse_radiance(self, hits, which, others=None, dirs: np.ndarray | None = None) -> np.ndarray:
        """Diffuse-only radiance of hits on ``others`` (default: the first reflector's), ``(R, 3)``.

        ρ_d Σ E (N·ω_l)⁺ over the lights (no shadows), plus ρ_d·D(N) of the environment; a miss
        (``which`` −1) of a ray along ``dirs`` sees the environment itself.
        """
        others = others if others is not None else self.others
        out = np.zeros((len(which), 3))
        if self.env is not None and dirs is not None:
            miss = which < 0
            out[miss] = cubemap.sample(self.env.levels[0], dirs[miss])
        skipped = next((r.index for r in self.reflectors if r.others is others), self.index)
        for k, obj in enumerate(others.objects):
            sel = np.nonzero(which == k)[0]
            if sel.size == 0:
                continue
            m = self.materials[obj.material]
            if m.surface is not None or not has_diffuse(m.model):
                raise SbrdfError(f"mirror: material {obj.material!r} has no rho_d or k_d for the diffuse-only "
                                 "reflection")
            rho_d = diffuse_value(m.model.unpack(m.lookup(hits.uv[sel])))
            if self.maps is not None:  # the light-mapped scene: ρ_d·E(uv) is all of its diffuse radiance
                from sbrdf_lib.lightmap import chart_uv, lookup

                out[sel] += rho_d * lookup(self.maps[k + (k >= skipped)], chart_uv(obj, hits.uv[sel]))
                continue
            pos, nrm = hits.position[sel], hits.normal[sel]
            for light in self.scene.lights:
                if light.type == "point":
                    d = light.vector - pos
                    r2 = np.einsum("ij,ij->i", d, d)
                    wl = d / np.sqrt(r2)[:, None]
                    E = light.power[None] / (r2 if light.falloff else np.ones_like(r2))[:, None]
                else:
                    wl, E = np.broadcast_to(light.vector, pos.shape), light.power[None]
                out[sel] += rho_d * E * np.maximum(np.einsum("ij,ij->i", nrm, wl), 0)[:, None]
            if self.env is not None:
                nu = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
                out[sel] += rho_d * cubemap.sample(self.env.map("D", self.env.diffuse_size), nu)
        return out

    def cpu_radiance(self, material, hits, view_dirs, pixels=None) -> np.ndarray:
        from sbrdf_lib.surface import cast, local_frame

        out = np.zeros((len(view_dirs), 3))
        refl = self.by_material.get(material.name)
        if refl is None:
            return out
        model = material.model
        n = hits.normal / np.linalg.norm(hits.normal, axis=1, keepdims=True)
        t, b = _frame_from_normal(n) if not material.anisotropic else local_frame(hits.normal, hits.tangent)[:2]
        wo_w = -view_dirs
        wo = np.stack([np.einsum("ij,ij->i", t, wo_w), np.einsum("ij,ij->i", b, wo_w), np.einsum("ij,ij->i", n, wo_w)], 1)
        idx = np.nonzero(wo[:, 2] > 0)[0]
        if idx.size == 0:
            return out
        params = {k: v[idx] for k, v in model.unpack(material.lookup(hits.uv[idx])).items()}
        origin = hits.position[idx] + 1e-6 * max(1.0, float(np.abs(hits.position).max())) * n[idx]
        meshes: dict = {}

        def incident(d):
            R, K = d.shape[:2]
            o = np.repeat(origin, K, axis=0)
            flat = d.reshape(-1, 3)
            h, which = cast(refl.others, self.materials, flat, o, meshes)
            return self.diffuse_radiance(h, which, refl.others, flat).reshape(R, K, 3)

        ids = idx if pixels is None else np.asarray(pixels)[idx]
        out[idx] = sampling.monte_carlo(model, params, wo[idx], (t[idx], b[idx], n[idx]), incident,
                                        mc_lobes(model, params, wo[idx]), self.mc_samples, self.seed, 0, ids,
                                        specular_only=True)
        return out

    # -- gl ---------------------------------------------------------------------------------------------------------

    def glsl(self, material, exprs):
        from .mirror_glsl import fragment_code

        refl = self.by_material.get(material.name)
        if refl is None:
            return "", []
        return fragment_code(self, refl, material, exprs)

    def gl_prepare(self, drawer) -> None:
        from .mirror_glsl import MirrorPass

        for i, r in enumerate(self.reflectors):
            r.gl = MirrorPass(self, r, i, drawer)

    def gl_uniforms(self, prog, first_unit: int) -> int:
        unit = first_unit
        for r in self.reflectors:
            unit += r.gl.uniforms(prog, unit)
        return unit - first_unit

    def gl_use(self, first_unit: int) -> int:
        unit = first_unit
        for r in self.reflectors:
            unit += r.gl.use(unit)
        return unit - first_unit

    def gl_frame(self, drawer) -> None:
        for r in self.reflectors:
            r.gl.render(drawer)

    def gl_camera(self, drawer) -> None:
        """The camera moved (a walkthrough): every mirrored camera follows it."""
        self.scene = drawer.scene
        for r in self.reflectors:
            r.gl.set_camera(drawer.scene.camera)

    def release(self) -> None:
        for r in self.reflectors:
            if r.gl is not None:
                r.gl.release()
                r.gl = None


__all__ = ["MirrorEffect", "Reflector", "lobes", "reflector_indices", "reflector_materials"]
