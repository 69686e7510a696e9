"""A shading-mapped material for the ``cpu`` and ``gl`` renderers.

A scene material with ``shading_map:`` (a ShadingMap or PowerShadingMap
store) and a ``model:`` chosen at render time shades by the map instead of
f_r · E · cos θ:

    r = σ · f_r(ω_o, ω_i) · cos θ_i,    L = S(uv, r) · E        (seed 002 Eq 2)

with the lookup variant and the behaviour above a_max the scene asks for.
Both renderers call the same definitions (:func:`sbrdf_shading.shade.shade`
and :func:`sbrdf_shading.glsl.shading_glsl`), so they agree like any other
material.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.store import open_artifact

from .glsl import shading_glsl, uniform_values
from .shade import ShadingData, shade

__all__ = ["ShadingSurface", "open_surface"]


def open_surface(art, model, params: dict, *, variant: str = "r", above_max: str = "clamp",
                 sigma: float = 1.0) -> ShadingSurface:
    """The renderers' adapter of the kinds' ``material``: a ShadingMap or PowerShadingMap artifact, looked up with
    ``model`` at the global parameter values ``params`` (name -> ``(1, C)``) and the scene material's options."""
    data = (ShadingData.from_artifacts(compressed=art) if art.kind == "PowerShadingMap"
            else ShadingData.from_artifacts(shading_map=art))
    return ShadingSurface(data, model, params, variant, above_max, sigma)


class ShadingSurface:
    """A scene material that shades by a shading map (the renderers' ``surface`` protocol)."""

    def __init__(self, data: ShadingData, model, params: dict, variant: str = "r", above_max: str = "clamp",
                 sigma: float = 1.0):
        self.data, self.model, self.params = data, model, {k: np.asarray(v)[0] for k, v in params.items()}
        self.variant, self.above_max, self.sigma = variant, above_max, float(sigma)

    @classmethod
    def open(cls, url: str, model, params: dict, variant: str, above_max: str, sigma: float) -> ShadingSurface:
        """From a ShadingMap store or a PowerShadingMap store (compressed)."""
        return open_surface(open_artifact(url, ("ShadingMap", "PowerShadingMap")), model, params, variant=variant,
                            above_max=above_max, sigma=sigma)

    # -- cpu ----------------------------------------------------------------------------------------------------------

    def radiance(self, uv: np.ndarray, wi: np.ndarray, wo: np.ndarray, irradiance: np.ndarray) -> np.ndarray:
        return shade(self.data, self.model, self.params, uv, wi, wo, irradiance, sigma=self.sigma,
                     variant=self.variant, above_max=self.above_max)

    # -- gl -----------------------------------------------------------------------------------------------------------

    def glsl(self) -> str:
        return shading_glsl(self.model, variant=self.variant, above_max=self.above_max, compressed=self.data.compressed)

    @staticmethod
    def glsl_radiance(wi: str, wo: str, irradiance: str) -> str:
        return f"shade(v_uv, {wi}, {wo}, {irradiance})"

    def gl_uniforms(self) -> dict:
        return uniform_values(self.data, self.model, self.params, variant=self.variant, sigma=self.sigma)

    def gl_textures(self, ctx) -> list:
        import moderngl

        def tex2d(a):
            V, U = a.shape[:2]
            t = ctx.texture((U, V), 3, np.ascontiguousarray(a, np.float32).tobytes(), dtype="f4")
            t.filter = (moderngl.LINEAR, moderngl.LINEAR)
            t.repeat_x = t.repeat_y = True
            return t

        if self.data.compressed:
            return [("u_k_s_map", tex2d(self.data.k_s)), ("u_exponent_map", tex2d(self.data.exponent))]
        slices = self.data.slices
        assert slices is not None, "ShadingData holds the full stack when it is not compressed"
        N, V, U = slices.shape[:3]
        t = ctx.texture3d((U, V, N), 3, np.ascontiguousarray(slices, np.float32).tobytes(), dtype="f4")
        t.filter = (moderngl.LINEAR, moderngl.LINEAR)
        t.repeat_x = t.repeat_y = True
        t.repeat_z = False
        return [("u_shading_map", t)]
