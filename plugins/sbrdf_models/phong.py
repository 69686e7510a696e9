"""phong: the modified (energy-normalised) Phong model of Lafortune & Willems 1994.

Seed 002 renders every mesostructure material with it (its ref [17]); it is
also the simplest specular model to fit and a check on the Lafortune lobes:
it is one lobe with C = (−1, −1, 1) and a magnitude tied to the exponent.

    f_r(ω_i, ω_o) = ρ_d + ρ_s · (n + 2)/(2π) · max(0, cos α)^n,    cos α = ω_o · reflect(ω_i)

with reflect(ω) = (−ω_x, −ω_y, ω_z) the mirror direction about the normal.

Units and energy: the diffuse albedo is π ρ_d (Lafortune & Willems' k_d is
π ρ_d); the (n + 2)/(2π) factor makes the lobe's directional albedo exactly
ρ_s at normal incidence and less elsewhere (the horizon cuts the lobe), so
π ρ_d + ρ_s ≤ 1 is energy conserving.  As a Lafortune lobe this is
ρ_s,Lafortune = ρ_s (n + 2)/(2π).

The fit form fits log n (as the Lafortune fit form does): n spans four
decades and the lobe depends on it logarithmically.

YAML::

    fit: {kind: Fit, plugin: lm, in: {samples: reflectance}, params: {model: phong}}
"""

from __future__ import annotations

import math

import numpy as np

from sbrdf_core.brdf import LOG_CAP, BRDFModel, LogFitForm, ModelParameter, above_horizon, positive_power
from sbrdf_core.constraints import clip_shape
from sbrdf_core.constraints_glsl import BIG, clip_lines, glsl_float, max_cosine_exponent

EXPONENT_BOUNDS = (0.1, 20000.0)


def fit_kernel(x, cfg, wi, wo, f, J):
    """f_r and ∂f_r/∂x in the fit form x = (ρ_d, ρ_s, log n) at one direction pair; zeros below the horizon.

    The lobe is :func:`~sbrdf_core.brdf.positive_power`'s: cos^n with n·log cos clipped to [−745, LOG_CAP], 0 where
    cos α ≤ 0.  ∂lobe/∂log n = n (cos^n/2π + lobe·log cos)."""
    for c in range(3):
        f[c] = 0.0
        for k in range(7):
            J[c, k] = 0.0
    if not (wi[2] > 0.0 and wo[2] > 0.0):  # not ≤ 0: NaN directions give 0, as above_horizon does
        return
    n = math.exp(x[6])
    cos_a = wi[2] * wo[2] - wi[0] * wo[0] - wi[1] * wo[1]
    p, log_c = 0.0, 0.0
    if cos_a > 0.0:
        log_c = math.log(cos_a)
        p = math.exp(min(max(n * log_c, -745.0), LOG_CAP))
    lobe = (n + 2.0) / (2.0 * math.pi) * p
    dlobe = (p / (2.0 * math.pi) + lobe * log_c) * n
    for c in range(3):
        f[c] = x[c] + x[3 + c] * lobe
        J[c, c] = 1.0
        J[c, 3 + c] = lobe
        J[c, 6] = x[3 + c] * dlobe


def project_kernel(x, cfg, lim, lo, hi):
    """:meth:`PhongModel.constrain` on one packed fit-form row ``x`` = (ρ_d, ρ_s, log n), in place, inside the box
    ``lo``, ``hi`` (which holds ρ_d ≤ peak and n ≤ the resolvable exponent): the fitting engine's projection.
    ``lim`` = (peak, has_peak).  Returns True."""
    for k in range(x.size):
        x[k] = min(max(x[k], lo[k]), hi[k])
    if lim[1] == 0.0:
        return True
    budget = max(lim[0] - max(x[0], x[1], x[2]), 0.0)
    rho = max(x[3], x[4], x[5])
    n = math.exp(x[6])
    n_peak = 2.0 * math.pi * budget / rho - 2.0 if rho > 0.0 else math.inf
    if n > n_peak * (1.0 + 1e-9):
        n = max(n_peak, EXPONENT_BOUNDS[0])
        x[6] = math.log(n)
    lobe_peak = rho * (n + 2.0) / (2.0 * math.pi)
    if lobe_peak > budget:
        for c in range(3, 6):
            x[c] *= budget / lobe_peak
    return True


class PhongModel(BRDFModel):
    name = "phong"
    #: What the sampling bounds (``LogFitForm.limit_box``): the sharpness the samples resolve.
    sharpness = ("exponent",)
    anisotropic = False
    reads_peak_cosine = False  # its peak is bounded on f_r itself
    fit_kernel = staticmethod(fit_kernel)
    project_kernel = staticmethod(project_kernel)
    parameters = (
        ModelParameter("rho_d", 3, (0.0, 10.0), (0.02, 0.25), 0.1, unit="sr^-1", doc="diffuse term", magnitude=True),
        ModelParameter("rho_s", 3, (0.0, 10.0), (0.05, 0.8), 0.3, unit="1", doc="specular albedo at normal incidence",
                       magnitude=True),
        ModelParameter("exponent", 1, EXPONENT_BOUNDS, (5.0, 200.0), 10.0, doc="Phong exponent n"),
    )

    @staticmethod
    def cos_alpha(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``ω_o · reflect(ω_i)``, (T, S)."""
        return wi[..., 2] * wo[..., 2] - wi[..., 0] * wo[..., 0] - wi[..., 1] * wo[..., 1]

    def eval(self, params, wi, wo):
        n = np.asarray(params["exponent"])[:, :1]
        lobe = (n + 2.0) / (2 * np.pi) * positive_power(self.cos_alpha(wi, wo), n)
        f = np.asarray(params["rho_d"])[:, None, :] + np.asarray(params["rho_s"])[:, None, :] * lobe[..., None]
        return np.where(above_horizon(wi, wo)[..., None], f, 0.0)

    def jacobian(self, params, wi, wo):
        up = above_horizon(wi, wo).astype(float)
        n = np.asarray(params["exponent"])[:, :1]
        x = self.cos_alpha(wi, wo)
        p = positive_power(x, n) * up
        lobe = (n + 2.0) / (2 * np.pi) * p
        logx = np.log(np.where(x > 0, x, 1.0))
        dlobe_dn = p / (2 * np.pi) + lobe * logx
        eye = np.eye(3)
        cols = [up[..., None] * eye[c] for c in range(3)] + [lobe[..., None] * eye[c] for c in range(3)]
        cols.append(np.asarray(params["rho_s"])[:, None, :] * dlobe_dn[..., None])
        return np.stack(cols, axis=-1)

    def glsl(self) -> str:
        """``vec3 brdf_phong(wi, wo, rho_d, rho_s, exponent)`` in the surface frame."""
        return (
            "vec3 brdf_phong(vec3 wi, vec3 wo, vec3 rho_d, vec3 rho_s, float exponent) {\n"
            "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
            "    float x = dot(vec3(-wi.xy, wi.z), wo);\n"
            "    float lobe = x > 0.0 ? (exponent + 2.0) * 0.15915494309 * exp(min(exponent * log(x), 60.0)) : 0.0;\n"
            "    return rho_d + rho_s * lobe;\n"
            "}\n"
        )

    def fit_form(self) -> LogFitForm:
        return LogFitForm(self, ("exponent",))

    def glsl_fit_constrain(self) -> str:
        """``brdf_fit_constrain``: :meth:`constrain` on the fit form (ρ_d, ρ_s, log n) in GLSL, for ``lm-gl``."""
        form = self.fit_form()
        lo, hi = (glsl_float(b) for b in EXPONENT_BOUNDS)
        return "\n".join(
            ["void brdf_fit_constrain(inout float x[7], float peak, float resolution, float peak_cosine, "
             "float growth, float max_theta) {"]
            + clip_lines(form)
            + ["    float n = exp(x[6]), n0 = n;",
               f"    if (resolution >= 0.0) n = min(n, {max_cosine_exponent()});",
               "    if (peak >= 0.0) {",
               "        float budget = max(peak - max(x[0], max(x[1], x[2])), 0.0);",
               "        float rho = max(x[3], max(x[4], x[5]));",
               f"        float n_peak = rho > 0.0 ? 6.28318530718 * budget / rho - 2.0 : {BIG};",
               f"        if (n > n_peak * (1.0 + 1e-9)) n = max(n_peak, {lo});",
               "        float lobe_peak = rho * (n + 2.0) / 6.28318530718;",
               "        float shrink = lobe_peak > budget ? budget / (lobe_peak > 0.0 ? lobe_peak : 1.0) : 1.0;",
               "        for (int c = 3; c < 6; ++c) x[c] *= shrink;",
               "    }",
               f"    if (n != n0) x[6] = log(clamp(n, {lo}, {hi}));",
               "}", ""])

    def albedo_bound(self, params):
        """π ρ_d + ρ_s per channel: the normalised lobe's albedo is ρ_s at normal incidence and less elsewhere."""
        return (np.pi * np.asarray(params["rho_d"]) + np.asarray(params["rho_s"])).max(axis=1)

    @staticmethod
    def project_limits(limits, T: int) -> np.ndarray:
        """Each texel's (peak, has_peak), what :func:`project_kernel` reads, ``(T, 2)``."""
        out = np.zeros((T, 2))
        if limits is not None and limits.peak is not None:
            out[:, 0], out[:, 1] = np.asarray(limits.peak, np.float64).reshape(T), 1.0
        return out

    def constrain(self, params, limits):
        """n no sharper than the sampling resolves, and a peak ρ_d + ρ_s (n + 2)/2π within ``limits.peak``.

        The peak bound lowers n (widens the lobe, keeping its albedo ρ_s)
        rather than ρ_s; only a lobe too bright even at the lowest n loses
        magnitude.
        """
        out, changed = super().constrain(params, limits)
        out, sharp = clip_shape(out, ("exponent",), high=limits.max_cosine_exponent())
        changed |= sharp
        if limits.peak is not None:
            budget = np.maximum(np.asarray(limits.peak)[:, None] - out["rho_d"].max(axis=1, keepdims=True), 0.0)
            rho = out["rho_s"].max(axis=1, keepdims=True)
            with np.errstate(divide="ignore", invalid="ignore"):
                n_peak = np.where(rho > 0, 2 * np.pi * budget / np.where(rho > 0, rho, 1.0) - 2.0, np.inf)
            n = out["exponent"]
            low = EXPONENT_BOUNDS[0]
            over = n > n_peak * (1 + 1e-9)
            out["exponent"] = np.where(over, np.maximum(n_peak, low), n)
            lobe_peak = rho * (out["exponent"] + 2.0) / (2 * np.pi)
            shrink = np.where(lobe_peak > budget, budget / np.where(lobe_peak > 0, lobe_peak, 1.0), 1.0)
            out["rho_s"] = out["rho_s"] * shrink
            changed |= over[:, 0] | (shrink[:, 0] < 1 - 1e-9)
        return out, changed
