"""ambient: a uniform sky, the example scene effect.

A constant radiance ``A`` arriving from every direction of the upper
hemisphere reflects as L = A ∫ f_r(ω_i, ω_o) cos θ_i dω_i, the directional
albedo times A.  The integral costs a quadrature per pixel; this effect takes
the one-sample estimate L ≈ π A f_r(n, ω_o) (the BRDF at normal incidence,
times the cosine-weighted solid angle π), which is exact for a Lambertian
surface and a cheap fill light for the rest.  Good enough to lift shadows out
of black, and small enough to show the whole scene-effect protocol
(``sbrdf_core.contracts.SceneEffect``; hits and frames from :mod:`sbrdf_lib.surface`): one term in numpy for the
``cpu`` renderer, the same term in GLSL for ``gl``, active only when the scene
asks for it.
"""

from __future__ import annotations

import math

import numpy as np

from sbrdf_lib.surface import local_frame

from .declarations import AMBIENT

NAME = "ambient"


class AmbientEffect:
    """L += π · radiance · f_r(n, ω_o), on every material (see the module docstring)."""

    name = NAME

    params = AMBIENT

    def __init__(self, *, radiance=[0.1, 0.1, 0.1]):  # noqa: B006 (read only)
        self.radiance = np.asarray(radiance, dtype=np.float64)

    # -- selection: only scenes that ask for it -----------------------------------------------------------------

    @staticmethod
    def wanted(scene) -> bool:
        return NAME in (getattr(scene, "effects", None) or {})

    @staticmethod
    def options(scene) -> dict:
        return dict(scene.effects[NAME] or {})

    def prepare(self, scene, materials, gl_context=None) -> None:
        """Nothing to precompute: the term is evaluated per pixel."""

    # -- cpu ----------------------------------------------------------------------------------------------------

    def cpu_radiance(self, material, hits, view_dirs: np.ndarray, pixels=None) -> np.ndarray:
        """``(R, 3)``: π A f_r(n, ω_o) at the hits, vectorised (zero where the surface faces away)."""
        t, b, n = local_frame(hits.normal, hits.tangent)
        wo_w = -view_dirs
        wo = np.stack([np.einsum("ij,ij->i", t, wo_w), np.einsum("ij,ij->i", b, wo_w),
                       np.einsum("ij,ij->i", n, wo_w)], 1)
        wi = np.broadcast_to(np.array([0.0, 0.0, 1.0]), wo.shape)
        params = material.model.unpack(material.lookup(hits.uv))
        f = material.model.eval(params, wi[:, None], wo[:, None])[:, 0]
        return math.pi * f * self.radiance

    # -- gl -----------------------------------------------------------------------------------------------------

    def glsl(self, material, exprs: dict) -> tuple[str, list[str]]:
        """One uniform, one statement after the lights (``wo``, ``L`` and the model's function are in scope)."""
        call = material.model.glsl_call("vec3(0.0, 0.0, 1.0)", "wo", exprs)
        return "uniform vec3 u_ambient_radiance;", [f"    L += {math.pi!r} * u_ambient_radiance * {call};"]

    def gl_prepare(self, drawer) -> None:
        """No textures or buffers."""

    def gl_uniforms(self, prog, first_unit: int) -> int:
        if "u_ambient_radiance" in prog:
            prog["u_ambient_radiance"].value = tuple(float(v) for v in self.radiance)
        return 0  # texture units used

    def gl_use(self, first_unit: int) -> int:
        return 0

    def gl_frame(self, drawer) -> None:
        """Nothing changes between frames."""

    def release(self) -> None:
        """Nothing to free."""
