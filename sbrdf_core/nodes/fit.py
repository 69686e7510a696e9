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

import time
from dataclasses import dataclass

import numpy as np

from ..artifacts import ParamMaps, SampledReflectance
from ..geometry import tile_directions
from .base import BuildContext, NodeKind, Output, Port


#: Bits of the ``flags`` map: why a texel's fit is missing or doubtful.  Stored
#: in the artifact's attributes too, so a reader needs no code to decode them.
FLAGS = {
    1: "no valid samples: parameters are the model defaults",
    2: "fewer valid samples than parameters: underdetermined, damped fit",
    4: "non-finite samples ignored",
    8: "iteration cap reached before convergence",
    16: "fitter produced non-finite values: parameters are the model defaults",
}
NO_SAMPLES, UNDERDETERMINED, NONFINITE_INPUT, NOT_CONVERGED, NONFINITE_RESULT = 1, 2, 4, 8, 16


@dataclass
class FitResult:
    """Per-texel fit output for a batch of T texels."""

    params: dict[str, np.ndarray]  # name -> (T, C), in the model's own form
    rms: np.ndarray  # (T,) sr^-1 over valid samples, RGB pooled
    samples: np.ndarray  # (T,) valid sample count
    flags: np.ndarray | None = None  # (T,) uint8 bits of FLAGS the fitter raised (e.g. NOT_CONVERGED)


def usable(f_r: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(f_r, valid)`` with non-finite samples invalid and every invalid sample 0.

    Fitters call this first: invalid samples may carry anything (NaN from a
    broken pixel, garbage from a saturated one) and weights of 0 do not stop
    NaN from propagating through ``0 · NaN``.
    """
    valid = np.asarray(valid, bool) & np.isfinite(f_r).all(axis=-1)
    return np.where(valid[..., None], f_r, 0.0), valid


def rms_error(model, params, f_r, valid, wi, wo) -> np.ndarray:
    """RMS of ``model − f_r`` over each texel's valid samples and RGB pooled (seed 000 §4.4), sr⁻¹."""
    diff = np.where(valid[..., None], model.eval(params, wi, wo) - f_r, 0.0)
    n = valid.sum(axis=1) * f_r.shape[-1]
    return np.sqrt(np.einsum("tsc,tsc->t", diff, diff) / np.maximum(n, 1))


def fit_tile(f_r, valid, light_pos, camera_pos, texels, size_mm, fitter, model, block_info=None):
    """Kernel: a ``(v, u, P, 3)`` tile -> ``(v, u, K + 4)`` = packed parameters, rms, samples, flags, seconds.

    Non-finite samples are dropped before the fitter sees them, and whatever
    the fitter returns, no NaN or inf reaches the maps: such texels get the
    model's defaults and a flag saying why.
    """
    t0 = time.perf_counter()
    (v0, v1), (u0, u1) = block_info[0]["array-location"][:2]
    wi, _, wo = tile_directions(texels, size_mm, (v0, v1), (u0, u1), light_pos, camera_pos)
    T = wi.shape[0]
    f_r = f_r.reshape(T, -1, 3).astype(np.float64)
    valid = valid.reshape(T, -1)
    finite = np.isfinite(f_r).all(axis=-1)
    flags = np.where((valid & ~finite).any(axis=1), NONFINITE_INPUT, 0).astype(np.uint8)
    f_r, valid = usable(f_r, valid)
    res: FitResult = fitter.fit(model, f_r, valid, wi, wo)
    if res.flags is not None:
        flags |= res.flags.astype(np.uint8)
    x = model.pack(res.params)
    bad = ~(np.isfinite(x).all(axis=1) & np.isfinite(res.rms))
    empty = res.samples == 0
    flags |= np.where(bad, NONFINITE_RESULT, 0).astype(np.uint8) | np.where(empty, NO_SAMPLES, 0).astype(np.uint8)
    flags |= np.where(~empty & (res.samples * 3 < model.size), UNDERDETERMINED, 0).astype(np.uint8)
    x[bad | empty] = model.pack(model.defaults(1))[0]
    rms = np.where(bad | empty, 0.0, res.rms)
    seconds = np.full(T, (time.perf_counter() - t0) / T)
    out = np.concatenate([x, rms[:, None], res.samples[:, None], flags[:, None], seconds[:, None]], axis=1)
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
            drop_axis=[3], chunks=f_r.chunks[:2] + ((K + 4,),), dtype=np.float32, name=f"fit-{ctx.node}",
        )
        arrays = {f"params/{name}": packed[..., s] for name, s in model.slices().items()}
        arrays["rms"] = packed[..., K]
        arrays["samples"] = packed[..., K + 1].astype(np.int32)
        arrays["flags"] = packed[..., K + 2].astype(np.uint8)
        arrays["fit_time_s"] = packed[..., K + 3]

        def finalize(art):
            rms, n, flags = art.read("rms"), art.read("samples"), art.read("flags")
            fitted = n > 0
            return {"summary": {
                "rms_mean": float(rms[fitted].mean()) if fitted.any() else None,
                "rms_max": float(rms[fitted].max()) if fitted.any() else None,
                "rms_p95": float(np.percentile(rms[fitted], 95)) if fitted.any() else None,
                "fit_time_s": float(art.read("fit_time_s").astype(np.float64).sum()),
                "texels_without_samples": int((~fitted).sum()),
                "texels_flagged": {FLAGS[b]: int(((flags & b) > 0).sum()) for b in FLAGS if ((flags & b) > 0).any()},
            }}

        return Output(
            arrays=arrays,
            attrs={
                "fitter": ctx.spec.name if ctx.spec else None,
                "flag_bits": {str(b): text for b, text in FLAGS.items()},
                "model": model.name,
                "model_config": dict(ctx.plugin.model_config),
                "parameters": model.describe(),
                "texels": samples.attrs["texels"],
                "size_mm": samples.attrs["size_mm"],
            },
            finalize=finalize,
        )
