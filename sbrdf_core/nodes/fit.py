"""Fit: per-texel BRDF-model parameters from sampled reflectance.

The node streams over texel tiles (one chunk of SampledReflectance = all poses
of a tile), derives ω_i and ω_r per texel from the stored geometry, and calls
the fitter plugin on a flat batch of texels.  Every fit writes an RMS error map
and the sample count per texel beside the parameter maps; texels with no
valid sample get the model's defaults and a sample count of 0 rather than NaN.

Fitter protocol: ``model_name`` and ``model_config`` attributes naming the
BRDF model to fit (the node constructs it from the registry), and
``fit(model, f_r, valid, wi, wo) -> FitResult``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..artifacts import ParamMaps, SampledReflectance
from ..geometry import tile_directions
from .base import BuildContext, NodeKind, Output, Port


@dataclass
class FitResult:
    """Per-texel fit output for a batch of T texels."""

    params: dict[str, np.ndarray]  # name -> (T, C)
    rms: np.ndarray  # (T,) sr^-1 over valid samples
    samples: np.ndarray  # (T,) valid sample count


def fit_tile(f_r, valid, light_pos, camera_pos, texels, size_mm, fitter, model, block_info=None):
    """Kernel: a ``(v, u, P, 3)`` tile -> ``(v, u, K + 2)`` = packed parameters, rms, samples."""
    (v0, v1), (u0, u1) = block_info[0]["array-location"][:2]
    wi, _, wo = tile_directions(texels, size_mm, (v0, v1), (u0, u1), light_pos, camera_pos)
    T = wi.shape[0]
    res: FitResult = fitter.fit(model, f_r.reshape(T, -1, 3).astype(np.float64), valid.reshape(T, -1), wi, wo)
    x = model.pack(res.params)
    empty = res.samples == 0
    if empty.any():  # no data: defaults, flagged by samples == 0
        x[empty] = model.pack(model.defaults(1))[0]
    rms = np.where(empty, 0.0, res.rms)
    if not (np.isfinite(x).all() and np.isfinite(rms).all()):
        raise FloatingPointError(f"fitter {type(fitter).__name__} produced non-finite parameters in texels v{v0}:{v1} u{u0}:{u1}")
    out = np.concatenate([x, rms[:, None], res.samples[:, None]], axis=1)
    return out.reshape(v1 - v0, u1 - u0, -1).astype(np.float32)


class Fit(NodeKind):
    name = "Fit"
    doc = "Fit a BRDF model per texel; writes parameter maps, RMS error map and sample counts."
    inputs = (Port("samples", (SampledReflectance,), "sampled reflectance (a single BRDF is a 1x1 grid)"),)
    output = ParamMaps
    plugin_category = "fitter"

    @classmethod
    def model(cls, ctx: BuildContext):
        return ctx.registry.create("brdf-model", ctx.plugin.model_name, dict(ctx.plugin.model_config))

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        samples = ctx.inputs["samples"]
        model = cls.model(ctx)
        f_r, valid = samples.array("f_r"), samples.array("valid")
        K = model.size
        packed = da.map_blocks(
            fit_tile, f_r, valid[..., None], samples.read("light_pos"), samples.read("camera_pos"),
            tuple(samples.attrs["texels"]), tuple(samples.attrs["size_mm"]), ctx.plugin, model,
            drop_axis=[3], chunks=f_r.chunks[:2] + ((K + 2,),), dtype=np.float32, name=f"fit-{ctx.node}",
        )
        arrays = {f"params/{name}": packed[..., s] for name, s in model.slices().items()}
        arrays["rms"] = packed[..., K]
        arrays["samples"] = packed[..., K + 1].astype(np.int32)

        def finalize(art):
            rms, n = art.read("rms"), art.read("samples")
            fitted = n > 0
            return {"summary": {
                "rms_mean": float(rms[fitted].mean()) if fitted.any() else None,
                "rms_p95": float(np.percentile(rms[fitted], 95)) if fitted.any() else None,
                "texels_without_samples": int((~fitted).sum()),
            }}

        return Output(
            arrays=arrays,
            attrs={
                "model": model.name,
                "model_config": dict(ctx.plugin.model_config),
                "parameters": model.describe(),
                "texels": samples.attrs["texels"],
                "size_mm": samples.attrs["size_mm"],
            },
            finalize=finalize,
        )
