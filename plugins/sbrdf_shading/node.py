"""Node kinds ``ShadingMap`` (RegisteredStack -> ShadingMap) and ``CompressShadingMap`` (-> PowerShadingMap).

``ShadingMap`` turns each registered light-arc image into "BRDF times
cosine" values for a unit light, b = L · r² / I (r the texel's distance to
the light, I the light's intensity from the capture), averages every image
over its valid texels and channels, and resamples the stack (Eq 1) with the
``(N, P)`` interpolation matrix of :mod:`sbrdf_shading.linearize`, lazily:
the averages are one dask reduction, the matrix a delayed function of them,
the slices an ``einsum``.  Invalid samples (saturated, off the sample) are
replaced by their image's average and counted (``filled_samples``).

``CompressShadingMap`` fits Eq 4 per texel tile (all N slices of a tile in
one chunk) and records the overall RMS as Table 1 reports it.
"""

from __future__ import annotations

import logging

import numpy as np

from sbrdf_core.artifacts import RegisteredStack
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output, Port
from sbrdf_core.params import Param

from .artifacts import PowerShadingMap, ShadingMap
from .compress import COARSE_STEP, EXPONENT_RANGE, FINE_STEP

logger = logging.getLogger(__name__)


def unit_light_factor(light_pos: np.ndarray, texels, size_mm, intensity: float) -> np.ndarray:
    """``(P, V, U)`` factor r² / I turning radiance into BRDF · cos for a unit light."""
    from sbrdf_core.geometry import texel_centres

    if not (np.isfinite(intensity) and intensity > 0):
        raise ValueError(f"the capture's light intensity must be positive, got {intensity!r}")
    p = texel_centres(tuple(texels), tuple(size_mm))
    d = np.asarray(light_pos, np.float64)[:, None, None, :] - p[None]
    return ((d * d).sum(-1) / intensity).astype(np.float32)


def elevation_deg(light_pos: np.ndarray) -> np.ndarray:
    """Light elevation from the normal at the sample centre, degrees."""
    lp = np.asarray(light_pos, np.float64)
    return np.degrees(np.arccos(np.clip(lp[:, 2] / np.linalg.norm(lp, axis=-1), -1.0, 1.0)))


class ShadingMapNode(NodeKind):
    name = "ShadingMap"
    doc = "Linearize a light-arc RegisteredStack into a shading map (Kautz et al. 2003 Eq 1; docs/shading-maps.md)."
    inputs = (Port("stack", (RegisteredStack,), "fixed-view images under a light moving along an arc"),)
    output = ShadingMap
    params = (
        Param("slices", "int", 8, "N, slices of the shading map (the paper: 8, a power of two for 3D textures)",
              bounds=(2, 256)),
        Param("tile", "int", 128, "texel tile edge of the stored chunks (all slices of a tile in one chunk)",
              bounds=(8, 4096)),
    )

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask
        import dask.array as da

        from .linearize import interpolation_weights, slice_averages

        stack = ctx.inputs["stack"]
        N, tile = int(ctx.params["slices"]), int(ctx.params["tile"])
        logger.info("ShadingMap of %s: %d slices", stack.url, N)
        U, V = stack.attrs["texels"]
        light_pos = stack.read("light_pos")
        P = len(light_pos)
        if P < 1:
            raise ValueError(f"ShadingMap: {stack.url} holds no accepted pose")
        intensity = float(stack.attrs.get("light", {}).get("intensity", 1.0))
        radiance = stack.array("radiance")
        valid = stack.array("valid")
        factor = da.from_array(unit_light_factor(light_pos, (U, V), stack.attrs["size_mm"], intensity),
                               chunks=valid.chunks)
        b = radiance * factor[..., None]
        ok = valid & da.isfinite(b).all(axis=-1)
        w = ok[..., None].astype(np.float64)
        count = w.sum(axis=(1, 2, 3)) * 3
        averages = da.where(count > 0, (da.where(ok[..., None], b, 0.0) * w).sum(axis=(1, 2, 3)) / da.maximum(count, 1), 0.0)
        W = da.from_delayed(dask.delayed(interpolation_weights)(averages, N), (N, P), dtype=np.float64)
        filled = da.where(ok[..., None], b, averages[:, None, None, None]).astype(np.float32)
        slices = da.einsum("np,pvuc->nvuc", W.astype(np.float32), filled.rechunk({0: -1}))
        r = da.from_delayed(dask.delayed(lambda a: slice_averages(max(float(np.max(a, initial=0.0)), 0.0), N))(averages),
                            (N,), dtype=np.float64)
        t = min(tile, max(U, V))

        def finalize(art):
            a = art.read("image_average")
            if not np.isfinite(a).all() or a.max(initial=0.0) <= 0:
                raise ValueError(f"ShadingMap: the images of {stack.url} have no positive average radiance")
            return {"a_max": float(a.max()), "filled_samples": int((~stack.read("valid")).sum())}

        return Output(
            arrays={"slices": slices.astype(np.float32), "slice_average": r, "image_average": averages,
                    "theta_i_deg": da.from_array(elevation_deg(light_pos))},
            chunks={"slices": (N, t, t, 3)},
            attrs={"slices": N, "texels": [int(U), int(V)], "size_mm": list(stack.attrs["size_mm"]),
                   "light_intensity": intensity, "values": "BRDF times cosine for a unit light, sr^-1"},
            finalize=finalize,
        )


class CompressShadingMapNode(NodeKind):
    name = "CompressShadingMap"
    doc = "Fit k_s r^K per texel and channel to a shading map (Kautz et al. 2003 Eq 4, coarse-then-fine search)."
    inputs = (Port("shading_map", (ShadingMap,), "the shading map to compress"),)
    output = PowerShadingMap
    params = (
        Param("exponent_range", "list", list(EXPONENT_RANGE), "[low, high] of the exponent K searched", length=2,
              item="float", bounds=(1e-6, None)),
        Param("coarse_step", "float", COARSE_STEP, "step of the first (coarse) pass over K", bounds=(1e-6, None)),
        Param("fine_step", "float", FINE_STEP, "step of the second pass, within one coarse step of its minimum",
              bounds=(1e-6, None)),
    )

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        from .compress import compress_tile

        sm = ctx.inputs["shading_map"]
        lo, hi = ctx.params["exponent_range"]
        coarse, fine = float(ctx.params["coarse_step"]), float(ctx.params["fine_step"])
        if not 0 < lo < hi:
            raise ValueError(f"CompressShadingMap: exponent_range must satisfy 0 < low < high, got {[lo, hi]}")
        if fine > coarse:
            raise ValueError(f"CompressShadingMap: fine_step ({fine}) must not exceed coarse_step ({coarse})")
        slices = sm.array("slices")
        N, V, U, C = slices.shape
        slices = slices.rechunk({0: -1, 3: -1})
        packed = da.map_blocks(compress_tile, slices, (lo, hi), coarse, fine, drop_axis=0,
                               chunks=(slices.chunks[1], slices.chunks[2], (2 * C + 1,)), dtype=np.float32,
                               name=ctx.key("shading-compress"))

        def finalize(art):
            rms = art.read("rms").astype(np.float64)
            return {"rms": float(np.sqrt(np.mean(rms**2))), "rms_relative": float(np.sqrt(np.mean(rms**2)) / sm.attrs["a_max"])}

        return Output(
            arrays={"k_s": packed[..., :C], "exponent": packed[..., C:2 * C], "rms": packed[..., 2 * C]},
            attrs={"a_max": float(sm.attrs["a_max"]), "slices": int(N), "texels": sm.attrs.get("texels"),
                   "size_mm": sm.attrs.get("size_mm"), "exponent_range": [lo, hi], "coarse_step": coarse,
                   "fine_step": fine, "image_average": sm.read("image_average").tolist(),
                   "theta_i_deg": sm.read("theta_i_deg").tolist()},
            finalize=finalize,
        )
