"""The plausibility limits in GLSL: what a model's optional ``glsl_fit_constrain`` is built from.

A GPU fitter projects every trial point onto the texel's
:class:`~sbrdf_core.types.Limits` inside its shader, so the constrained
Levenberg–Marquardt needs no round trip to the CPU.  A model's
``glsl_fit_constrain()`` defines

.. code-block:: glsl

    void brdf_fit_constrain(inout float x[K], float peak, float resolution, float peak_cosine,
                            float growth, float max_theta);

projecting the packed fit-form parameters ``x`` exactly as the fit form's
numpy ``constrain`` does (in float32); a negative ``peak``, ``resolution``,
``peak_cosine`` or ``growth`` means that bound is off (``None``).  This module
packs :class:`Limits` for it (:func:`pack_limits`) and holds the GLSL twins
of :meth:`BRDFModel.constrain <sbrdf_core.brdf.BRDFModel.constrain>`'s
default clip, :func:`~sbrdf_core.constraints.clip_shape` (roughness floor)
and :func:`~sbrdf_core.constraints.mirror_peak` /
:func:`~sbrdf_core.constraints.widen_to_peak`, which models assemble.
"""

from __future__ import annotations

import numpy as np

from .types import HALF_MAX

#: The function a model's ``glsl_fit_constrain()`` defines (``K`` = ``fit_form().size``).
SIGNATURE = ("void brdf_fit_constrain(inout float x[K], float peak, float resolution, float peak_cosine, "
             "float growth, float max_theta)")
#: Floats per texel in :func:`pack_limits`: peak, resolution, peak_cosine.
LIMITS_STRIDE = 3
#: "Infinite" in the GLSL below (float32's largest is 3.4e38; comparisons only).
BIG = "3.0e38"


def pack_limits(limits, T: int) -> np.ndarray:
    """Per-texel ``(peak, resolution, peak_cosine)``, ``(T, 3)`` float32, −1 where that bound is off."""
    out = np.full((T, LIMITS_STRIDE), -1.0, np.float32)
    for k, name in enumerate(("peak", "resolution", "peak_cosine")):
        value = getattr(limits, name)
        if value is not None:
            out[:, k] = np.broadcast_to(np.asarray(value, np.float64), (T,))
    return out


def scalars(limits) -> tuple[float, float]:
    """``(growth, max_theta)`` as the GLSL takes them (growth −1 when off)."""
    return (-1.0 if limits.growth is None else float(limits.growth)), float(limits.max_theta)


def glsl_float(v: float) -> str:
    """A GLSL float literal (float32 rounding of ``v``)."""
    return repr(float(np.float32(v))) if np.isfinite(v) else BIG


def clip_lines(form) -> list[str]:
    """GLSL lines of :meth:`BRDFModel.constrain`'s default on fit-form ``x``: every parameter into its declared
    bounds (in the fit form: a log parameter's bounds are the logs of the model's), then ρ_d ≤ ``peak``."""
    lo, hi = form.bounds()
    lines = [f"    x[{k}] = clamp(x[{k}], {glsl_float(a)}, {glsl_float(b)});" for k, (a, b) in enumerate(zip(lo, hi))]
    sl = form.slices()
    if "rho_d" in sl:
        lines.append("    if (peak >= 0.0) {")
        lines += [f"        x[{k}] = min(x[{k}], peak);" for k in range(sl["rho_d"].start, sl["rho_d"].stop)]
        lines.append("    }")
    return lines


def max_cosine_exponent() -> str:
    """GLSL expression of :meth:`Limits.max_cosine_exponent` from ``resolution`` (≥ 0: the bound is on)."""
    return f"({glsl_float(4.0 * HALF_MAX)} / (max(resolution, 1e-4) * max(resolution, 1e-4)))"


def min_roughness() -> str:
    """GLSL expression of :meth:`Limits.min_roughness` from ``resolution`` (≥ 0: the bound is on)."""
    return f"(resolution * {glsl_float(1.0 / (4.0 * np.sqrt(np.log(2.0))))})"


def widen_to_peak(function: str, decl: list[tuple[str, str]], names: tuple[str, ...], caps: tuple[float, ...],
                  azimuths: int = 1, n: int = 24, steps: int = 16) -> str:
    """GLSL for :func:`~sbrdf_core.constraints.mirror_peak` and :func:`~sbrdf_core.constraints.widen_to_peak`.

    ``function`` is the model's GLSL (``glsl()``) function, called as
    ``function(wi, wo, <decl names in order>)``; ``decl`` is its parameters after
    ``wi, wo`` as ``(type, name)``; ``names`` are the roughness parameters
    widened by one common factor up to ``caps``.  ``azimuths``: 1 for an
    isotropic model (the numpy version's second azimuth gives the same
    values), 2 for φ = 0 and π/2.  Defines ``float limits_mirror_peak(<decl>,
    float max_theta, bool cosine)`` and ``void limits_widen(<decl, names
    inout>, float peak, float peak_cosine, float max_theta)``.
    """
    plain = ", ".join(f"{t} {v}" for t, v in decl)
    inout = ", ".join(f"{'inout ' if v in names else ''}{t} {v}" for t, v in decl)
    args = ", ".join(v for _, v in decl)
    trial_args = ", ".join(f"t_{v}" if v in names else v for _, v in decl)
    room = " ".join(f"room = max(room, log({glsl_float(c)} / max({v}, 1e-30)));" for v, c in zip(names, caps))
    trial = " ".join(f"float t_{v} = min({v} * e, {glsl_float(c)});" for v, c in zip(names, caps))
    final = " ".join(f"{v} = min({v} * e, {glsl_float(c)});" for v, c in zip(names, caps))
    return f"""
float limits_mirror_peak({plain}, float max_theta, bool cosine) {{
    float best = -{BIG};
    for (int i = 0; i < {n}; ++i) {{
        float th = max_theta * float(i) / {float(n - 1)}, st = sin(th), ct = cos(th);
        for (int a = 0; a < {azimuths}; ++a) {{
            vec3 d = a == 0 ? vec3(st, 0.0, ct) : vec3(0.0, st, ct);
            vec3 f = {function}(d, vec3(-d.xy, d.z), {args});
            if (cosine) f *= ct * ct;
            bool bad = any(isnan(f)) || any(isinf(f));
            best = max(best, bad ? {BIG} : max(f.r, max(f.g, f.b)));
        }}
    }}
    return best;
}}

void limits_widen({inout}, float peak, float peak_cosine, float max_theta) {{
    bool cosine = peak_cosine >= 0.0;
    float bound = cosine ? peak_cosine : peak;
    if (bound < 0.0) return;
    if (!(limits_mirror_peak({args}, max_theta, cosine) > bound * (1.0 + 1e-6))) return;
    float room = -{BIG};
    {room}
    float lo = 0.0, hi = max(room, 0.0);
    for (int i = 0; i < {steps}; ++i) {{
        float mid = 0.5 * (lo + hi), e = exp(mid);
        {trial}
        if (limits_mirror_peak({trial_args}, max_theta, cosine) <= bound) hi = mid; else lo = mid;
    }}
    float e = exp(hi);
    {final}
}}
"""


def microfacet_constrain(form, function: str, decl: list[tuple[str, str]], names: tuple[str, ...],
                         caps: tuple[float, ...], azimuths: int = 1) -> str:
    """``brdf_fit_constrain`` for a :class:`~sbrdf_core.brdf.LogFitForm` of a microfacet model whose numpy
    ``constrain`` is the default clip, :func:`~sbrdf_core.constraints.clip_shape` with ``min_roughness`` on
    ``names``, then :func:`~sbrdf_core.constraints.widen_to_peak` (Cook–Torrance, Ward).

    ``decl`` names the model-form arguments of ``function`` after ``wi, wo``
    (``vec3`` magnitudes, ``float`` roughness), in fit-form order.
    """
    sl = form.slices()
    lo, hi = form.bounds()
    lines = [f"void brdf_fit_constrain(inout float x[{form.size}], float peak, float resolution, "
             "float peak_cosine, float growth, float max_theta) {"]
    lines += clip_lines(form)
    for t, v in decl:
        if t == "vec3":
            s = sl[v].start
            lines.append(f"    vec3 {v} = vec3(x[{s}], x[{s + 1}], x[{s + 2}]);")
        else:
            lines.append(f"    float {v} = exp(x[{sl[f'log_{v}'].start}]), {v}_0 = {v};")
    lines.append("    if (resolution >= 0.0) {")
    lines += [f"        {v} = max({v}, {min_roughness()});" for v in names]
    lines.append("    }")
    lines.append(f"    limits_widen({', '.join(v for _, v in decl)}, peak, peak_cosine, max_theta);")
    for v in names:
        k = sl[f"log_{v}"].start
        lines.append(f"    if ({v} != {v}_0) x[{k}] = log(clamp({v}, {glsl_float(np.exp(lo[k]))}, "
                     f"{glsl_float(np.exp(hi[k]))}));")
    lines.append("}")
    return widen_to_peak(function, decl, names, caps, azimuths) + "\n".join(lines) + "\n"
