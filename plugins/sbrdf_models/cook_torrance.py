"""cook-torrance: the microfacet model with Beckmann or GGX facets and Schlick Fresnel.

The physically based reference the compact models are judged against: it
sharpens and brightens toward grazing, which Lafortune lobes cannot (seed 000
§7.1), and it is what modern renderers and material libraries exchange.

    f_r(ω_i, ω_o) = ρ_d + F(ω_i·h) D(h) G(ω_i, ω_o) / (4 cos θ_i cos θ_o),    h = (ω_i + ω_o)/|ω_i + ω_o|

- D, ``distribution: beckmann``:  exp(−tan²θ_h/α²) / (π α² cos⁴θ_h)
- D, ``distribution: ggx``:  α² / (π (cos²θ_h (α² − 1) + 1)²)
- F, Schlick:  F0 + (1 − F0)(1 − ω_i·h)⁵, per RGB channel
- G, Smith height-correlated (Heitz 2014):  1 / (1 + Λ(ω_i) + Λ(ω_o)) with the Λ of the chosen
  distribution (exact: Beckmann Λ(a) = (e^(−a²)/(a√π) − erfc a)/2, a = 1/(α tan θ);
  GGX Λ = (√(1 + α² tan²θ) − 1)/2).  It is reciprocal, accounts for the masking/shadowing
  correlation the separable form ignores, and is no harder to differentiate.

There is no separate specular scale: F0 is the specular colour and magnitude
(for small α the lobe's albedo at normal incidence is ≈ F0); it has three
channels because metals have a coloured specular (a dielectric has F0 ≈ 0.04,
grey).  ρ_d is the diffuse BRDF value (albedo / π), not Fresnel-weighted.  Grazing: the
cosines are floored at :data:`COS_FLOOR` (0.0001° from the horizon), where G
already goes to 0 like cos θ, so f stays finite.  The fit form fits log α.

YAML::

    fit: {kind: Fit, plugin: lm, in: {samples: reflectance},
          params: {model: cook-torrance, model_params: {distribution: ggx}}}
"""

from __future__ import annotations

import math

import numpy as np

from sbrdf_core.brdf import BRDFModel, LogFitForm, ModelParameter, above_horizon
from sbrdf_core.constraints import WidenedRoughness
from sbrdf_core.constraints_glsl import microfacet_constrain

from . import declarations

COS_FLOOR = 1e-6
ALPHA_BOUNDS = (1e-3, 2.0)
SQRT_PI = float(np.sqrt(np.pi))
#: ``distribution`` as :meth:`CookTorranceModel.kernel_config` numbers it.
DISTRIBUTIONS = ("beckmann", "ggx")


def fit_kernel(x, cfg, wi, wo, f, J):
    """f_r and ∂f_r/∂x in the fit form x = (ρ_d, F0, log α) at one direction pair; zeros below the horizon.
    ``cfg`` = (index in :data:`DISTRIBUTIONS`,).  The floors and clips are :meth:`CookTorranceModel._terms`'."""
    for c in range(3):
        f[c] = 0.0
        for k in range(7):
            J[c, k] = 0.0
    if not (wi[2] > 0.0 and wo[2] > 0.0):  # not ≤ 0: NaN directions give 0, as above_horizon does
        return
    beckmann = cfg[0] == 0.0
    alpha = math.exp(x[6])
    a2 = alpha * alpha
    ci, co = max(wi[2], COS_FLOOR), max(wo[2], COS_FLOOR)
    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    hh = max(hx * hx + hy * hy + hz * hz, 1e-300)
    cos2_h = min(max(max(hz, 0.0) ** 2 / hh, COS_FLOOR**2), 1.0)
    cos_d = min(max((wi[0] * hx + wi[1] * hy + wi[2] * hz) / math.sqrt(hh), 0.0), 1.0)
    if beckmann:
        tan2_h = (1.0 - cos2_h) / cos2_h
        D = math.exp(-tan2_h / a2) / (math.pi * a2 * cos2_h * cos2_h)
        dD = D * (2.0 * tan2_h / (a2 * alpha) - 2.0 / alpha)
    else:
        kk = cos2_h * a2 + (1.0 - cos2_h)
        D = a2 / (math.pi * kk * kk)
        dD = D * (2.0 / alpha - 4.0 * cos2_h * alpha / kk)
    # Smith Λ(ω_i) + Λ(ω_o) and its α derivative, for G = 1/(1 + Λ_i + Λ_o)
    lam, dlam = 1.0, 0.0
    for cos_t in (ci, co):
        tan2 = max(1.0 - cos_t * cos_t, 0.0) / (cos_t * cos_t)
        if beckmann:
            a = 1.0 / (alpha * math.sqrt(max(tan2, 1e-30)))
            g = math.exp(-a * a) / (a * SQRT_PI)
            lam += 0.5 * (g - math.erfc(a))
            dlam += 0.5 * g / alpha
        else:
            xg = a2 * tan2
            root = math.sqrt(1.0 + xg)
            lam += 0.5 * xg / (1.0 + root)
            dlam += 0.5 * alpha * tan2 / root
    G = 1.0 / lam
    dG = -G * G * dlam
    denom = 4.0 * ci * co
    spec = D * G / denom
    dspec = (dD * G + D * dG) / denom
    schlick = (1.0 - cos_d) ** 5
    for c in range(3):
        F = x[3 + c] + (1.0 - x[3 + c]) * schlick
        f[c] = x[c] + F * spec
        J[c, c] = 1.0
        J[c, 3 + c] = spec * (1.0 - schlick)
        J[c, 6] = F * dspec * alpha


def schlick_lobe(params, wi, wo, spec, schlick):
    """f_r = ρ_d + F·spec with Schlick's F = F0 + (1 − F0)·``schlick`` per RGB channel, 0 below the horizon,
    ``(T, S, 3)``: a microfacet model given its D·G/(4 cos θ_i cos θ_o) term ``spec`` ``(T, S)``."""
    f0 = np.asarray(params["f0"])[:, None, :]
    f = np.asarray(params["rho_d"])[:, None, :] + (f0 + (1.0 - f0) * schlick[..., None]) * spec[..., None]
    return np.where(above_horizon(wi, wo)[..., None], f, 0.0)


def schlick_lobe_jacobian(params, wi, wo, spec, dspec, schlick):
    """∂f_r/∂x of :func:`schlick_lobe`: ρ_d (3 columns), F0 (3), then one column per shape parameter, from
    ``dspec`` ``(T, S, K)`` (∂spec by each); ``(T, S, 3, 6 + K)``."""
    up = above_horizon(wi, wo).astype(float)
    f0 = np.asarray(params["f0"])[:, None, :]
    F = f0 + (1.0 - f0) * schlick[..., None]
    eye = np.eye(3)
    cols = [up[..., None] * eye[c] for c in range(3)]
    cols += [(spec * (1.0 - schlick))[..., None] * eye[c] for c in range(3)]
    cols += [F * dspec[..., k:k + 1] for k in range(dspec.shape[-1])]
    return np.stack(cols, axis=-1)


class CookTorranceModel(WidenedRoughness, BRDFModel):
    name = "cook-torrance"
    #: What the sampling bounds (``LogFitForm.limit_box``): the sharpness the samples resolve.
    roughness = ("alpha",)
    anisotropic = False
    fit_kernel = staticmethod(fit_kernel)
    parameters = (
        ModelParameter("rho_d", 3, (0.0, 10.0), (0.02, 0.25), 0.1, unit="sr^-1", doc="diffuse term", magnitude=True),
        ModelParameter("f0", 3, (0.0, 1.0), (0.02, 0.9), 0.04, unit="1", doc="Fresnel reflectance at normal incidence",
                       magnitude=True),
        ModelParameter("alpha", 1, ALPHA_BOUNDS, (0.05, 0.5), 0.2, doc="roughness"),
    )

    params = declarations.COOK_TORRANCE

    def __init__(self, *, distribution: str = "ggx"):
        if distribution not in ("beckmann", "ggx"):
            raise ValueError(f"cook-torrance: distribution must be 'beckmann' or 'ggx', got {distribution!r}")
        self.distribution = distribution

    def kernel_config(self) -> np.ndarray:
        """``distribution`` as a number for :func:`fit_kernel`."""
        return np.array([float(DISTRIBUTIONS.index(self.distribution))])

    # -- the three factors, each with its α derivative ------------------------------------

    def _distribution(self, cos2_h, alpha):
        """D and ∂D/∂α, (T, S) each."""
        a2 = alpha * alpha
        if self.distribution == "beckmann":
            tan2 = (1.0 - cos2_h) / cos2_h
            D = np.exp(-tan2 / a2) / (np.pi * a2 * cos2_h * cos2_h)
            return D, D * (2 * tan2 / (a2 * alpha) - 2 / alpha)
        k = cos2_h * a2 + (1.0 - cos2_h)
        D = a2 / (np.pi * k * k)
        return D, D * (2 / alpha - 4 * cos2_h * alpha / k)

    def _smith_lambda(self, cos_t, alpha):
        """Smith Λ(ω) and ∂Λ/∂α for cos θ = ``cos_t`` (already floored), (T, S) each."""
        tan2 = np.maximum(1.0 - cos_t * cos_t, 0.0) / (cos_t * cos_t)
        if self.distribution == "beckmann":
            from scipy.special import erfc  # imported on first use: listing plugins stays light

            a = 1.0 / (alpha * np.sqrt(np.maximum(tan2, 1e-30)))
            g = np.exp(-a * a) / (a * SQRT_PI)
            return 0.5 * (g - erfc(a)), 0.5 * g / alpha
        x = alpha * alpha * tan2
        root = np.sqrt(1.0 + x)
        return 0.5 * x / (1.0 + root), 0.5 * alpha * tan2 / root

    def _terms(self, params, wi, wo):
        alpha = np.asarray(params["alpha"])[:, :1]
        up = above_horizon(wi, wo)
        ci = np.maximum(wi[..., 2], COS_FLOOR)
        co = np.maximum(wo[..., 2], COS_FLOOR)
        h = wi + wo
        hh = np.maximum(np.einsum("tsk,tsk->ts", h, h), 1e-300)
        cos2_h = np.clip(np.maximum(h[..., 2], 0.0) ** 2 / hh, COS_FLOOR**2, 1.0)
        cos_d = np.clip(np.einsum("tsk,tsk->ts", wi, h) / np.sqrt(hh), 0.0, 1.0)
        D, dD = self._distribution(cos2_h, alpha)
        li, dli = self._smith_lambda(ci, alpha)
        lo, dlo = self._smith_lambda(co, alpha)
        G = 1.0 / (1.0 + li + lo)
        dG = -G * G * (dli + dlo)
        denom = 4.0 * ci * co
        spec = np.where(up, D * G / denom, 0.0)
        dspec = np.where(up, (dD * G + D * dG) / denom, 0.0)
        schlick = (1.0 - cos_d) ** 5
        return spec, dspec, schlick

    def eval(self, params, wi, wo):
        spec, _, schlick = self._terms(params, wi, wo)
        return schlick_lobe(params, wi, wo, spec, schlick)

    def jacobian(self, params, wi, wo):
        spec, dspec, schlick = self._terms(params, wi, wo)
        return schlick_lobe_jacobian(params, wi, wo, spec, dspec[..., None], schlick)

    # -- renderer and fitter support -------------------------------------------------------------

    def glsl(self) -> str:
        """``vec3 brdf_cook_torrance(wi, wo, rho_d, f0, alpha)`` in the surface frame (plus a Λ helper)."""
        if self.distribution == "beckmann":
            d = ("    float tan2h = (1.0 - c2h) / c2h;\n"
                 "    float D = exp(-tan2h / a2) / (3.14159265359 * a2 * c2h * c2h);\n")
            lam = ("float cook_torrance_lambda(float c, float alpha) {\n"
                   "    float t = sqrt(max(1.0 - c * c, 0.0)) / c;\n"
                   "    float a = 1.0 / (alpha * max(t, 1e-15));\n"
                   "    if (a > 9.0) return 0.0;\n"
                   "    // erfc(a) = u p(u) exp(-a^2), Abramowitz & Stegun 7.1.26 (|error| < 1.5e-7)\n"
                   "    float u = 1.0 / (1.0 + 0.3275911 * a);\n"
                   "    float p = u * (0.254829592 + u * (-0.284496736 + u * (1.421413741 + u * (-1.453152027 + u * 1.061405429))));\n"
                   "    return 0.5 * exp(-a * a) * (1.0 / (a * 1.7724538509) - p);\n"
                   "}\n")
        else:
            d = ("    float k = c2h * a2 + (1.0 - c2h);\n"
                 "    float D = a2 / (3.14159265359 * k * k);\n")
            lam = ("float cook_torrance_lambda(float c, float alpha) {\n"
                   "    float x = alpha * alpha * max(1.0 - c * c, 0.0) / (c * c);\n"
                   "    return 0.5 * x / (1.0 + sqrt(1.0 + x));\n"
                   "}\n")
        return (
            lam
            + "vec3 brdf_cook_torrance(vec3 wi, vec3 wo, vec3 rho_d, vec3 f0, float alpha) {\n"
            "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
            "    float ci = max(wi.z, 1e-6), co = max(wo.z, 1e-6), a2 = alpha * alpha;\n"
            "    vec3 h = wi + wo;\n"
            "    float hh = max(dot(h, h), 1e-30);\n"
            "    float c2h = clamp(h.z * h.z / hh, 1e-12, 1.0);\n"
            "    float cd = clamp(dot(wi, h) * inversesqrt(hh), 0.0, 1.0);\n"
            + d +
            "    float G = 1.0 / (1.0 + cook_torrance_lambda(ci, alpha) + cook_torrance_lambda(co, alpha));\n"
            "    vec3 F = f0 + (1.0 - f0) * pow(1.0 - cd, 5.0);\n"
            "    return rho_d + F * (D * G / (4.0 * ci * co));\n"
            "}\n"
        )

    def fit_form(self) -> LogFitForm:
        return LogFitForm(self, ("alpha",))

    def glsl_fit_constrain(self) -> str:
        """``brdf_fit_constrain``: :meth:`constrain` on the fit form in GLSL (the bounds, ρ_d ≤ peak, α ≥ the
        resolvable roughness, α widened by bisection until the mirror peak fits), for ``lm-gl``."""
        return self.glsl() + microfacet_constrain(self.fit_form(), "brdf_cook_torrance",
                                                  [("vec3", "rho_d"), ("vec3", "f0"), ("float", "alpha")],
                                                  ("alpha",), (ALPHA_BOUNDS[1],))
