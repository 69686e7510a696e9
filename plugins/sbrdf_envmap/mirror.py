"""The ``mirror`` scene effect: planar reflectors (Mühlbacher §4.5) for plane objects with ``reflector: true``.

``gl`` (real time): every frame the scene *without* the plane is drawn from
the camera mirrored about the plane (geometry behind the plane clipped) into
a buffer of radiance, world position and normal, diffuse-only as in the
thesis (ρ_d × the point and directional lights, no shadows); the radiance
gets a MIP chain.  Each specular sample direction ω_i of the plane's
material is projected into that buffer: intersect the ray (P, ω_i) with the
tangent plane stored at the pixel's own mirror look-up, project the hit
with the mirror camera, then once more with the tangent plane found there
(the refinement step; ``refinements`` sets how often).  A pixel's filter
level comes from the lobe's four extreme directions projected the same way
(ellipse area / samples, log₄), once per pixel.  The samples are the
deterministic patterns and estimator of :mod:`.sampling`.

``cpu`` (the reference): Monte Carlo over the same lobes with real ray
casting: the radiance of the first object hit, diffuse-only by the same
definition.  Both add the *specular* reflection of the other objects
(f_r − ρ_d); the plane's own lighting by the lights is the renderer's.

Limits: one reflector, with a material of its own; not combined with an
environment map (the reflected objects would have to occlude it); alpha
masks are ignored in the mirror pass.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_core.params import Param

from . import lobes, sampling
from .effect import _frame_from_normal, mc_lobes

logger = logging.getLogger(__name__)


class MirrorEffect:
    name = "mirror"

    params = (
        Param("samples", "int", 7, "deterministic samples per lobe", bounds=(1, 64)),
        Param("estimator", "str", "4.25", "ratio estimator (Eq 4.23, 4.24 or 4.25)", choices=("4.23", "4.24", "4.25")),
        Param("xi_border", "float", 0.01, "lobe cut", bounds=(1e-6, 0.5)),
        Param("ring_radius", "float", 0.6, "xi_1 of the ring", bounds=(0.0, 1.0)),
        Param("line_threshold", "float", 4.0, "anisotropy ratio for the line pattern", bounds=(1.0, None)),
        Param("refinements", "int", 1, "tangent-plane refinement steps of the projection (the thesis: 1)", bounds=(0, 8)),
        Param("mc_samples", "int", 64, "cpu reference: Monte Carlo samples per strategy and pixel", bounds=(1, 1 << 20)),
        Param("seed", "int", 0, "seed of the scrambled Sobol points", bounds=(0, None)),
    )

    def __init__(self, *, samples: int = 7, estimator: str = "4.25", xi_border: float = sampling.XI_BORDER,
                 ring_radius: float = sampling.RING_RADIUS, line_threshold: float = 4.0, refinements: int = 1,
                 mc_samples: int = 64, seed: int = 0):
        self.samples, self.estimator, self.xi_border = samples, estimator, xi_border
        self.ring_radius, self.line_threshold, self.refinements = ring_radius, line_threshold, refinements
        self.mc_samples, self.seed = mc_samples, seed
        self._gl = None

    @staticmethod
    def wanted(scene) -> bool:
        return any(o.shape == "plane" and o.params.get("reflector") for o in scene.objects)

    @staticmethod
    def options(scene) -> dict:
        return {}

    @staticmethod
    def check(scene) -> list[str]:
        """The scene-level conditions of :meth:`prepare`, checked when the graph is validated."""
        idx = [k for k, o in enumerate(scene.objects) if o.shape == "plane" and o.params.get("reflector")]
        if len(idx) > 1:
            return [f"one reflector: true plane is supported, got {len(idx)}"]
        if scene.section("environment") is not None:
            return ["a reflector: true plane together with an environment map is not "
                    "supported (reflected objects do not occlude the environment yet)"]
        obj = scene.objects[idx[0]]
        if sum(o.material == obj.material for o in scene.objects) > 1:
            return [f"the reflector's material {obj.material!r} must not be used by other "
                    "objects (give the plane a material of its own)"]
        return []

    def prepare(self, scene, materials=None, gl_context=None) -> None:
        problems = self.check(scene)
        if problems:
            raise SbrdfError(f"{scene.file}: {problems[0]}")
        idx = [k for k, o in enumerate(scene.objects) if o.shape == "plane" and o.params.get("reflector")]
        self.index = idx[0]
        obj = scene.objects[self.index]
        self.material = obj.material
        self.scene, self.materials = scene, materials or {}
        self.others = dataclasses.replace(scene, objects=tuple(o for k, o in enumerate(scene.objects) if k != self.index))
        p0 = obj.matrix[:3, 3]
        n = obj.matrix[:3, :3] @ np.array([0.0, 0.0, 1.0])
        n /= np.linalg.norm(n)
        if np.dot(n, scene.camera.position - p0) < 0:
            n = -n
        self.plane = (p0, n)
        centre, radius = scene.bounds()
        self.far = float(4 * radius + np.linalg.norm(scene.camera.position - centre))  # a point "at infinity"

    # -- cpu: Monte Carlo with ray casting --------------------------------------------------------------------------

    def diffuse_radiance(self, hits, which) -> np.ndarray:
        """Diffuse-only radiance ρ_d Σ E (N·ω_l)⁺ of hits on :attr:`others` (no shadows), ``(R, 3)``."""
        out = np.zeros((len(which), 3))
        for k, obj in enumerate(self.others.objects):
            sel = np.nonzero(which == k)[0]
            if sel.size == 0:
                continue
            m = self.materials[obj.material]
            if m.surface is not None or "rho_d" not in {p.name for p in m.model.parameters}:
                raise SbrdfError(f"mirror: material {obj.material!r} has no rho_d for the diffuse-only reflection")
            rho_d = np.asarray(m.model.unpack(m.lookup(hits.uv[sel]))["rho_d"])
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
        return out

    def cpu_radiance(self, material, hits, view_dirs, pixels=None) -> np.ndarray:
        from sbrdf_lib.surface import cast, local_frame

        out = np.zeros((len(view_dirs), 3))
        if material.name != self.material:
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
        meshes = {}

        def incident(d):
            R, K = d.shape[:2]
            o = np.repeat(origin, K, axis=0)
            h, which = cast(self.others, self.materials, d.reshape(-1, 3), o, meshes)
            return self.diffuse_radiance(h, which).reshape(R, K, 3)

        ids = idx if pixels is None else np.asarray(pixels)[idx]
        out[idx] = sampling.monte_carlo(model, params, wo[idx], (t[idx], b[idx], n[idx]), incident,
                                        mc_lobes(model, params, wo[idx]), self.mc_samples, self.seed, 0, ids,
                                        specular_only=True)
        return out

    # -- gl ---------------------------------------------------------------------------------------------------------

    def glsl(self, material, exprs):
        from .mirror_glsl import fragment_code

        if material.name != self.material:
            return "", []
        return fragment_code(self, material, exprs)

    def gl_prepare(self, drawer) -> None:
        from .mirror_glsl import MirrorPass

        self._gl = MirrorPass(self, drawer)

    def gl_uniforms(self, prog, first_unit: int) -> int:
        return self._gl.uniforms(prog, first_unit)

    def gl_use(self, first_unit: int) -> int:
        return self._gl.use(first_unit)

    def gl_frame(self, drawer) -> None:
        self._gl.render(drawer)

    def release(self) -> None:
        if self._gl is not None:
            self._gl.release()
            self._gl = None


__all__ = ["MirrorEffect", "lobes"]
