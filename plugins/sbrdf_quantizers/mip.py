"""Mip: MIP levels of a fitted SBRDF, stored in the ParamMaps they were built from (seed 000 Ch 5, notes §10.1).

A coarse texel's right answer is the BRDF-space average of the fine texels it
covers; no parameter set reproduces it exactly.  ``method`` chooses how each
level is made from the one above it (level 0 is the fit itself):

``refit``
    McAllister's sample–blend–refit (:func:`~sbrdf_quantizers.interpolate.mip_refit`):
    average the four children's sampled BRDFs, fit the model to the average;
``average``
    average the children's parameters (what texture hardware does; for comparison);
``samples``
    fit each level to the 2×2-downsampled SampledReflectance the material was
    fitted from (:func:`~sbrdf_quantizers.interpolate.mip_refit_samples`; needs ``in: {samples: ...}``).

The output is the input ParamMaps, every array unchanged, plus
``mip/<l>/<parameter>`` for l = 1 … L, level l being ``(V >> l) × (U >> l)``
(odd edges dropped, the sizes OpenGL gives MIP levels), and an attribute
``mip``: ``{levels: L, method, shapes: [[V, U], ...] (level 0 first), error: [...]}``
where ``error[l-1]`` is the mean RMS (sr⁻¹, uniform direction pairs) of level l
against the BRDF-space average of its children.  Every ParamMaps consumer
(Quantize, Render, Select) reads it as before; the renderers use the levels
when a scene material says ``filter: trilinear``.  YAML::

    mip: {kind: Mip, in: {params: fit}, params: {method: refit}}

The levels are computed in memory (one LM fit per coarse texel for ``refit``),
in the node's prepare step (the runner's scheduler and progress bar): the
texel count of level 1 is a quarter of the fit's.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from sbrdf_core.artifacts import ParamMaps, SampledReflectance
from sbrdf_core.errors import SbrdfError
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output, Port
from sbrdf_core.params import Param

log = logging.getLogger(__name__)


def max_levels(V: int, U: int) -> int:
    """Levels below 0 until the smaller side is 1 texel."""
    return max(0, int(np.floor(np.log2(max(1, min(V, U))))))


def build_levels(model, params: dict, method: str = "refit", levels: int | None = None, n_dirs: int = 16,
                 iterations: int = 50, samples: dict | None = None) -> list[dict]:
    """Levels 1 … L of ``params`` (``{name: (V, U, C)}``) made by ``method``; a list of parameter dicts.

    ``samples`` (method ``samples``): ``{f_r (V, U, P, 3), valid (V, U, P), size_mm, light_pos, camera_pos}``.
    """
    from . import interpolate

    V, U = next(iter(params.values())).shape[:2]
    L = max_levels(V, U) if levels is None else min(int(levels), max_levels(V, U))
    out, current = [], {k: np.asarray(v, np.float64) for k, v in params.items()}
    f, valid = (None, None) if samples is None else (np.asarray(samples["f_r"], np.float64), np.asarray(samples["valid"]))
    for _ in range(L):
        if method == "average":
            nxt = interpolate.mip_lerp(current)
        elif method == "refit":
            nxt = interpolate.mip_refit(model, current, n_dirs=n_dirs, iterations=iterations)
        elif method == "samples":
            if samples is None or f is None or valid is None:
                raise ValueError("MIP method 'samples' needs the samples")
            nxt = interpolate.mip_refit_samples(model, f, valid, None, samples["size_mm"], samples["light_pos"],
                                                samples["camera_pos"], iterations, interpolate.mip_lerp(current))
            f, valid = interpolate.downsample_samples(f, valid)
        else:
            raise ValueError(f"unknown MIP method {method!r}")
        out.append({k: np.asarray(v, np.float32) for k, v in nxt.items()})
        current = {k: np.asarray(v, np.float64) for k, v in nxt.items()}
    return out


def level_errors(model, params: dict, levels: list[dict], n_dirs: int = 16) -> list[float]:
    """Mean RMS (sr⁻¹) of each level against the BRDF-space average of the children in the level above."""
    from . import interpolate

    errs, parent = [], params
    for lv in levels:
        ref = interpolate.brdf_average(model, {k: np.asarray(v, np.float64) for k, v in parent.items()}, n_dirs)
        errs.append(float(np.mean(interpolate.mip_error(model, lv, ref, n_dirs))))
        parent = lv
    return errs


class Mip(NodeKind):
    name = "Mip"
    doc = ("MIP levels of fitted ParamMaps (McAllister's sample-blend-refit, parameter averaging, or refits to the "
           "downsampled samples), stored beside level 0 as mip/<l>/<parameter>")
    inputs = (Port("params", (ParamMaps,), "fitted parameter maps (level 0)"),
              Port("samples", (SampledReflectance,), "the samples they were fitted from (method: samples)",
                   optional=True))
    output = ParamMaps
    params = (
        Param("method", "str", "refit", "how a level is made from the one above: refit its children's averaged "
              "sampled BRDFs, average their parameters, or refit the downsampled samples",
              choices=("refit", "average", "samples")),
        Param("levels", "int", None, "levels below 0 (default: until the smaller side is 1 texel)", nullable=True,
              bounds=(0, 16)),
        Param("directions", "int", 16, "Fibonacci directions per side of the sampled BRDFs blended and refitted "
              "(12 misses sharp lobes: refits that match the set but peak between its directions)",
              bounds=(2, 64)),
        Param("iterations", "int", 50, "LM iterations per refit", bounds=(1, 10000)),
    )

    @classmethod
    def prepare(cls, ctx: BuildContext) -> dict:
        """The levels, their errors and the seconds they took: one delayed task over the concrete level 0."""
        import dask

        p = ctx.params
        art = ctx.inputs["params"]
        if p["method"] == "samples" and "samples" not in ctx.inputs:
            raise SbrdfError(f"node {ctx.node!r}: method: samples needs in: {{samples: <SampledReflectance>}}")
        model = ctx.plugins().create("brdf-model", art.attrs["model"], dict(art.attrs.get("model_config", {})))
        base = {q.name: art.array(f"params/{q.name}") for q in model.parameters}
        samples = None
        if p["method"] == "samples":
            s = ctx.inputs["samples"]
            samples = {"f_r": s.array("f_r"), "valid": s.array("valid"), "size_mm": tuple(s.attrs["size_mm"]),
                       "light_pos": s.read("light_pos"), "camera_pos": s.read("camera_pos")}
        return {"levels": dask.delayed(_make_levels)(model, base, p["method"], p["levels"], p["directions"],
                                                     p["iterations"], samples)}

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        p = ctx.params
        art = ctx.inputs["params"]
        prepared = ctx.prepared
        if prepared is None:  # built outside a runner (a test, a notebook): compute it here
            import dask

            wanted = cls.prepare(ctx)
            prepared = dict(zip(wanted, dask.compute(*wanted.values())))
        levels, errors, seconds = prepared["levels"]
        model = ctx.plugins().create("brdf-model", art.attrs["model"], dict(art.attrs.get("model_config", {})))
        names = [q.name for q in model.parameters]
        base = {n: art.array(f"params/{n}") for n in names}
        V, U = next(iter(base.values())).shape[:2]
        shapes = [[V, U]] + [list(next(iter(lv.values())).shape[:2]) for lv in levels]
        log.info("node %r: %d MIP levels by %s in %.1f s; mean error per level %s", ctx.node, len(levels),
                 p["method"], seconds, [f"{e:.3g}" for e in errors])
        arrays = {n: art.array(n) for n in art.names() if not n.startswith("mip/")}
        for l, lv in enumerate(levels, 1):
            for n in names:
                arrays[f"mip/{l}/{n}"] = da.from_array(lv[n])
        attrs = {k: v for k, v in art.attrs.items()
                 if k not in ("kind", "version", "token", "complete", "provenance", "run", "summary", "mip")}
        attrs["mip"] = {"levels": len(levels), "method": p["method"], "shapes": shapes, "error": errors,
                        "seconds": seconds}
        summary = dict(art.attrs.get("summary", {}))
        return Output(arrays=arrays, attrs=attrs, finalize=lambda a: {"summary": summary})


def _make_levels(model, base, method, levels, n_dirs, iterations, samples):
    """``(levels, errors, seconds)`` from concrete level-0 maps (and samples): what ``Mip.prepare`` computes."""
    t0 = time.perf_counter()
    out = build_levels(model, base, method, levels, n_dirs, iterations, samples)
    seconds = time.perf_counter() - t0
    return out, level_errors(model, base, out, n_dirs), seconds


def read_levels(art, model) -> list[dict]:
    """The lazy MIP levels 1 … L of a ParamMaps artifact (``[]`` when it has none)."""
    L = int((art.attrs.get("mip") or {}).get("levels", 0))
    return [{q.name: art.array(f"mip/{l}/{q.name}") for q in model.parameters} for l in range(1, L + 1)]
