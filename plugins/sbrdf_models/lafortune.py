"""lafortune: generalized cosine lobes, McAllister's SBRDF representation (seed 000 §4.2, §6.5).

    f_r(ω_i, ω_r) = ρ_d + Σ_j ρ_s,j · max(0, C_x,j ω'_i,x ω'_r,x + C_y,j ω'_i,y ω'_r,y + C_z,j ω_i,z ω_r,z)^n_j

with ω' the directions rotated about the normal by the per-texel anisotropy
angle β (C' = R(−β)·C·R(β), Eq 4.4).  The lobe shape (C, n) is shared by the
RGB channels; ρ_d and ρ_s are RGB in sr⁻¹.  ``max(0, x)^n`` everywhere: a
negative generalized dot product has no real fractional power.

The per-texel maps are named by lobe j: ``rho_s_<j>``, ``c_xy_<j>`` (``c_x_<j>``
and ``c_y_<j>`` with ``anisotropic: true``), ``c_z_<j>``, ``exponent_<j>``; one
``beta`` with ``beta: true``; ``rho_m`` with ``mirror: true`` (rendered, never fitted).

Equivalences (a fit is judged modulo these; :meth:`LafortuneModel.canonical`
picks one representative): (e·ρ_s, C·e^(−1/n)) is the same lobe for any e > 0;
β ≡ β + π; β + π/2 with C_x ↔ C_y swapped is the same BRDF; lobes may be
listed in any order (canonical: ascending C_x + C_y, forward lobes first).

The fit form fixes C_z = 1 (so ρ_s is the lobe's peak value at normal
incidence) and fits log n: the raw form is singular along the rescale
direction and badly scaled in n.

YAML::

    fit: {kind: Fit, plugin: lm, in: {samples: reflectance},
          params: {model: lafortune, model_params: {lobes: 2, anisotropic: true, beta: true}}}
"""

from __future__ import annotations

import copy
import math

import numpy as np

from sbrdf_core.brdf import LOG_CAP, BRDFModel, ModelParameter, above_horizon, positive_power
from sbrdf_core.constraints_glsl import BIG, clip_lines, glsl_float, max_cosine_exponent
from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

#: McAllister's initial guesses (§4.3.1): lobe 1 forward (mirror), lobe 2 back-scatter.
INITIAL_LOBES = ((-1.0, -1.0, 1.0, 10.0), (1.0, 1.0, 1.0, 5.0))
EXPONENT_BOUNDS = (0.1, 20000.0)
#: A lobe whose ρ_s (every channel) is below this, sr⁻¹, contributes nothing measurable: see to_model.
DEAD_LOBE = 1e-9
#: A lobe whose peak is below this fraction of the texel's peak budget and of its ρ_d contributes nothing visible.
NEGLIGIBLE = 1e-3
#: The neutral shape a dead lobe is reset to: a mirror cosine lobe, n = 1 (bounded under interpolation).
NEUTRAL_EXPONENT = 1.0
#: A lobe LM has lost (``fit_trapped``): dead, its peak ρ_s at most the first fraction of the strongest lobe's; or a
#: spike on a sample or two, at most the second fraction with n within the last factor of its bound.
TRAPPED = (1e-3, 0.1, 0.95)
#: A multi-lobe texel whose cost per sample is over this multiple of its tile's median is fitted again
#: (``fit_outlier_ratio``): on benchmarks/fit.py's Lafortune data, 2 lobes, 10 of 1024 texels settled with two lobes
#: on the mirror peak or one at n ≈ 20000 and fitted 3-8x worse than the peer; one lobe: not worth its time (the
#: missing lobe's energy varies texel to texel, so a third of a tile are "outliers" a restart cannot improve).
OUTLIER_RATIO = 2.0
#: Longest LM step in a lobe's log n (the fit form's ``max_step``): n changes by at most e^0.5 ≈ 1.65× a step.
#: Unbounded, a quarter of 1-lobe texels on McAllister-like data (benchmarks/fit.py) took a Gauss–Newton step
#: that multiplied n several times over, cost more than the start, and needed about 20 evaluations instead of 6
#: while λ grew until the step was short enough; bounded: mean evaluations 9.7 → 7.4 (1 lobe), 11.0 → 10.0 (2).
MAX_LOG_EXPONENT_STEP = 0.5
#: Lobe-1 exponents tried for the starting point (the text's n = 10 among them).
START_EXPONENTS = (3.0, 10.0, 40.0, 160.0, 640.0)
C_BOUNDS = (-10.0, 10.0)
#: C_z > 0: the fit form's C_z = 1 gauge needs it, and a lobe with C_z ≤ 0 is
#: dark at normal incidence (no measured material in the seed needs one).
CZ_BOUNDS = (0.05, 10.0)
#: C_x, C_y in the C_z = 1 gauge, so the fit form converts back inside C_BOUNDS
#: (a lobe with |C_x| > 10·C_z is clipped to that ratio when converted).
FIT_C_BOUNDS = C_BOUNDS


class LafortuneModel(BRDFModel):
    name = "lafortune"
    reads_peak_cosine = False  # lobes are bounded on f_r itself (bound_lobes), not as microfacet lobes

    params = (
        Param("lobes", "int", 1, "number of cosine lobes", bounds=(0, 8)),
        Param("anisotropic", "bool", False, "separate C_x and C_y per lobe (otherwise C_x = C_y)"),
        Param("beta", "bool", False, "per-texel anisotropy angle β shared by the lobes (needs anisotropic)"),
        Param("mirror", "bool", False, "add the mirror term ρ_m (rendered by renderers, not fitted)"),
    )

    def __init__(self, *, lobes: int = 1, anisotropic: bool = False, beta: bool = False, mirror: bool = False):
        self.channels = 3
        if beta and not anisotropic:
            raise ValueError("lafortune: beta: true needs anisotropic: true (an isotropic lobe has no direction)")
        self.lobes, self.anisotropic, self.has_beta, self.mirror = lobes, anisotropic, beta, mirror
        self.parameters = self._declare(fit_form=False)
        # The compiled exponent scan of the initial guess finds 1-2 lobes' basin; 3+ lobes need starts (§4.3.1).
        self.suggested_starts = 1 if lobes <= 2 else 4

    def single_channel(self) -> LafortuneModel:
        """The same lobes on scalar (luminance) data, ρ_d and ρ_s with one channel: McAllister's lobe fit."""
        out = copy.copy(self)
        out.channels = 1
        out.parameters = out._declare(fit_form=False)
        return out

    # -- declarations ------------------------------------------------------------------

    def _declare(self, fit_form: bool) -> tuple[ModelParameter, ...]:
        nc = self.channels
        ps = [ModelParameter("rho_d", nc, (0.0, 100.0), (0.02, 0.25), 0.1, unit="sr^-1", doc="diffuse term",
                             magnitude=True)]
        for j in range(1, self.lobes + 1):
            cx0, _, cz0, n0 = INITIAL_LOBES[min(j, 2) - 1]
            back = j == 2
            ps.append(ModelParameter(f"rho_s_{j}", nc, (0.0, 1e6), (0.05, 0.3) if back else (0.2, 2.0), 0.3,
                                     unit="sr^-1", doc=f"lobe {j} magnitude", magnitude=True))
            cx_typ = (0.8, 1.0) if back else (-1.0, -0.95)
            names = ("c_x", "c_y") if self.anisotropic else ("c_xy",)
            for nm in names:
                ps.append(ModelParameter(f"{nm}_{j}", 1, FIT_C_BOUNDS if fit_form else C_BOUNDS, cx_typ, cx0, doc=f"lobe {j} {nm.replace('_', ' ').upper()}"))
            if fit_form:
                ps.append(ModelParameter(f"log_exponent_{j}", 1, tuple(np.log(EXPONENT_BOUNDS)),
                                         (np.log(2.0), np.log(20.0)) if back else (np.log(5.0), np.log(200.0)),
                                         float(np.log(n0)), doc=f"lobe {j} log n"))
            else:
                ps.append(ModelParameter(f"c_z_{j}", 1, CZ_BOUNDS, (0.9, 1.0), cz0, doc=f"lobe {j} C_z"))
                ps.append(ModelParameter(f"exponent_{j}", 1, EXPONENT_BOUNDS, (2.0, 20.0) if back else (5.0, 200.0), n0,
                                         doc=f"lobe {j} exponent n"))
        if self.has_beta:
            lim = 2 * np.pi if fit_form else np.pi / 2
            ps.append(ModelParameter("beta", 1, (-lim, lim), (-np.pi / 4, np.pi / 4), 0.0, unit="rad",
                                     doc="anisotropy direction, rotation about the normal"))
        if self.mirror and not fit_form:
            ps.append(ModelParameter("rho_m", 3, (0.0, 1.0), (0.0, 0.0), 0.0, doc="mirror term (not fitted)"))
        return tuple(ps)

    # -- lobes in one shape, whatever the configuration --------------------------------------

    def lobe_list(self, params) -> list[dict[str, np.ndarray]]:
        """Per lobe ``{rho_s (T,3), c_x, c_y, c_z, exponent (T,1)}`` for any configuration."""
        out = []
        for j in range(1, self.lobes + 1):
            cx = params[f"c_x_{j}"] if self.anisotropic else params[f"c_xy_{j}"]
            cy = params[f"c_y_{j}"] if self.anisotropic else cx
            out.append({"rho_s": params[f"rho_s_{j}"], "c_x": cx, "c_y": cy,
                        "c_z": params[f"c_z_{j}"], "exponent": params[f"exponent_{j}"]})
        return out

    def lobe_dots(self, params, wi, wo):
        """``(pxx, pyy, pzz)``: ω_i, ω_r component products in the anisotropy frame, (T, S) each.

        Every lobe is ``x = C_x·pxx + C_y·pyy + C_z·pzz``; fitters that scan lobe shapes (McAllister's
        luminance lobe fit) reuse these products for all candidates.
        """
        if self.has_beta:
            b = np.asarray(params["beta"])[:, 0][:, None]
            c, s = np.cos(b), np.sin(b)
            ix, iy = c * wi[..., 0] + s * wi[..., 1], -s * wi[..., 0] + c * wi[..., 1]
            ox, oy = c * wo[..., 0] + s * wo[..., 1], -s * wo[..., 0] + c * wo[..., 1]
        else:
            ix, iy, ox, oy = wi[..., 0], wi[..., 1], wo[..., 0], wo[..., 1]
        return ix * ox, iy * oy, wi[..., 2] * wo[..., 2], (ix, iy, ox, oy)

    # -- evaluation --------------------------------------------------------------------------

    def eval(self, params, wi, wo):
        """f_r in NumPy, for any configuration and broadcast: the reference :func:`fit_kernel` is tested against."""
        pxx, pyy, pzz, _ = self.lobe_dots(params, wi, wo)
        f = np.broadcast_to(np.asarray(params["rho_d"])[:, None, :], wi.shape[:2] + (self.channels,)).copy()
        for lobe in self.lobe_list(params):
            x = lobe["c_x"][:, :1] * pxx + lobe["c_y"][:, :1] * pyy + lobe["c_z"][:, :1] * pzz
            f += lobe["rho_s"][:, None, :] * positive_power(x, lobe["exponent"][:, :1])[..., None]
        return np.where(above_horizon(wi, wo)[..., None], f, 0.0)

    def jacobian(self, params, wi, wo):
        return self._jacobian(params, wi, wo, fit_form=False)

    def _jacobian(self, params, wi, wo, fit_form):
        """Analytic ∂f/∂x in the natural form or the fit form (log n, no C_z column)."""
        up = above_horizon(wi, wo).astype(float)
        pxx, pyy, pzz, (ix, iy, ox, oy) = self.lobe_dots(params, wi, wo)
        cols: list[np.ndarray] = []
        C = self.channels
        eye = np.eye(C)
        cols += [up[..., None] * eye[c] for c in range(C)]  # rho_d
        dbeta = 0.0
        for lobe in self.lobe_list(params):
            n = lobe["exponent"][:, :1]
            x = lobe["c_x"][:, :1] * pxx + lobe["c_y"][:, :1] * pyy + lobe["c_z"][:, :1] * pzz
            s = positive_power(x, n) * up
            ds_dx = n * positive_power(x, n - 1.0) * up  # n x^(n-1), 0 where x <= 0
            rho = lobe["rho_s"][:, None, :]  # (T,1,3)
            cols += [s[..., None] * eye[c] for c in range(C)]
            if self.anisotropic:
                cols += [rho * (ds_dx * pxx)[..., None], rho * (ds_dx * pyy)[..., None]]
            else:
                cols.append(rho * (ds_dx * (pxx + pyy))[..., None])
            if not fit_form:
                cols.append(rho * (ds_dx * pzz)[..., None])
            logx = np.log(np.where(x > 0, x, 1.0))
            ds_dn = s * logx * (n if fit_form else 1.0)  # ∂/∂log n = n ∂/∂n
            cols.append(rho * ds_dn[..., None])
            if self.has_beta:
                # d(ω'_x)/dβ = ω'_y, d(ω'_y)/dβ = −ω'_x  =>  dx/dβ = (C_x − C_y)(i'_y o'_x + i'_x o'_y)
                dx_db = (lobe["c_x"][:, :1] - lobe["c_y"][:, :1]) * (iy * ox + ix * oy)
                dbeta = dbeta + rho * (ds_dx * dx_db)[..., None]
        if self.has_beta:
            cols.append(np.broadcast_to(dbeta, wi.shape[:2] + (C,)))
        if self.mirror and not fit_form:
            cols += [np.zeros(wi.shape[:2] + (C,))] * 3
        return np.stack(cols, axis=-1)

    def glsl(self) -> str:
        """``vec3 brdf_lafortune(wi, wo, rho_d, rho_s[j], c[j], exponent[j], beta)`` in the surface frame."""
        L = self.lobes
        rot = ("    float cb = cos(beta), sb = sin(beta);\n"
               "    wi.xy = vec2(cb * wi.x + sb * wi.y, -sb * wi.x + cb * wi.y);\n"
               "    wo.xy = vec2(cb * wo.x + sb * wo.y, -sb * wo.x + cb * wo.y);\n")
        arrays = f"vec3 rho_s[{max(L, 1)}], vec3 c[{max(L, 1)}], float exponent[{max(L, 1)}], float beta"
        return (
            f"vec3 brdf_lafortune(vec3 wi, vec3 wo, vec3 rho_d, {arrays}) {{\n"
            "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
            + (rot if self.has_beta else "")
            + "    vec3 f = rho_d;\n"
            f"    for (int j = 0; j < {L}; ++j) {{\n"
            "        float x = dot(c[j] * wi, wo);\n"
            "        if (x > 0.0) f += rho_s[j] * exp(min(exponent[j] * log(x), 60.0));\n"
            "    }\n"
            "    return f;\n"
            "}\n"
        )

    def glsl_call(self, wi, wo, args):
        """Gathers the per-lobe parameters into the arrays :meth:`glsl` takes."""
        L = max(self.lobes, 1)
        if self.lobes == 0:
            rho_s, c, n = "vec3[1](vec3(0.0))", "vec3[1](vec3(0.0))", "float[1](0.0)"
        else:
            js = range(1, self.lobes + 1)
            cx = [args[f"c_x_{j}"] if self.anisotropic else args[f"c_xy_{j}"] for j in js]
            cy = [args[f"c_y_{j}"] if self.anisotropic else args[f"c_xy_{j}"] for j in js]
            rho_s = f"vec3[{L}](" + ", ".join(args[f"rho_s_{j}"] for j in js) + ")"
            c = f"vec3[{L}](" + ", ".join(f"vec3({x}, {y}, {args[f'c_z_{j}']})" for j, x, y in zip(js, cx, cy)) + ")"
            n = f"float[{L}](" + ", ".join(args[f"exponent_{j}"] for j in js) + ")"
        beta = args["beta"] if self.has_beta else "0.0"
        return f"brdf_lafortune({wi}, {wo}, {args['rho_d']}, {rho_s}, {c}, {n}, {beta})"

    def glsl_fit_constrain(self) -> str:
        """``brdf_fit_constrain``: the fit form's :meth:`~LafortuneFitForm.constrain` in GLSL (the bounds,
        ρ_d ≤ peak, then :func:`bound_lobes` per lobe: n ≤ the resolvable exponent, ρ_s within the budget, |C|
        shrunk until ρ_s·m^n fits and m^n ≤ growth, all ρ_s scaled by the lobes' common share), for ``lm-gl``."""
        if self.channels != 3:
            raise ValueError("lafortune: the GLSL fit constraint is for RGB lobes, not a single-channel model")
        form = self.fit_form()
        K, sl = form.size, form.slices()
        f = glsl_float
        lines = [f"void brdf_fit_constrain(inout float x[{K}], float peak, float resolution, float peak_cosine, "
                 "float growth, float max_theta) {"]
        lines += clip_lines(form)
        if self.lobes:
            lines += ["    bool finite_budget = peak >= 0.0;",
                      "    float budget = finite_budget ? max(peak - max(x[0], max(x[1], x[2])), 0.0) : 0.0;",
                      "    float s2 = sin(max_theta) * sin(max_theta), c2 = cos(max_theta) * cos(max_theta);",
                      f"    float n_cap = resolution >= 0.0 ? {max_cosine_exponent()} : {BIG};",
                      "    float total = 0.0;",
                      f"    float r_scale[{self.lobes}], c_scale[{self.lobes}], n_new[{self.lobes}];"]
        names = ("c_x", "c_y") if self.anisotropic else ("c_xy",)
        for j in range(1, self.lobes + 1):
            r, ln = sl[f"rho_s_{j}"].start, sl[f"log_exponent_{j}"].start
            cs = [sl[f"{nm}_{j}"].start for nm in names]
            cabs = f"abs(x[{cs[0]}])" if len(cs) == 1 else f"max(abs(x[{cs[0]}]), abs(x[{cs[1]}]))"
            i = j - 1
            lines += ["    {",
                      f"        float nn = clamp(min(exp(x[{ln}]), n_cap), {f(EXPONENT_BOUNDS[0])}, "
                      f"{f(EXPONENT_BOUNDS[1])});",
                      f"        float rmax = max(x[{r}], max(x[{r + 1}], x[{r + 2}]));",
                      "        float rs = finite_budget && rmax > budget ? budget / (rmax > 0.0 ? rmax : 1.0) : 1.0;",
                      "        float rr = rmax * rs;",
                      f"        float log_m = rr > 0.0 && finite_budget ? log(budget / rr) / nn : {BIG};",
                      "        if (growth >= 0.0) log_m = min(log_m, log(max(growth, 1.0)) / nn);",
                      f"        float c_allowed = s2 > 0.0 ? max((exp(min(log_m, 50.0)) - c2) / s2, 1.0) : {BIG};",
                      f"        float cabs = {cabs};",
                      "        float cs = cabs > c_allowed ? c_allowed / (cabs > 0.0 ? cabs : 1.0) : 1.0;",
                      "        float m = max(1.0, cabs * cs * s2 + c2);",
                      # numpy caps the exponent at 700; a finite budget already holds rr·m^n ≤ budget, so float32's
                      # 80 only matters where the budget is off and the share is 1 anyway
                      "        total += rr > 0.0 ? rr * exp(min(nn * log(m), 80.0)) : 0.0;",
                      f"        r_scale[{i}] = rs; c_scale[{i}] = cs; n_new[{i}] = nn;",
                      "    }"]
        if self.lobes:
            lines.append("    float share = finite_budget && total > budget ? budget / (total > 0.0 ? total : 1.0) : 1.0;")
        for j in range(1, self.lobes + 1):
            r, ln = sl[f"rho_s_{j}"].start, sl[f"log_exponent_{j}"].start
            i = j - 1
            lines += [f"    for (int c = 0; c < 3; ++c) x[{r} + c] *= r_scale[{i}] * share;"]
            lines += [f"    x[{sl[f'{nm}_{j}'].start}] *= c_scale[{i}];" for nm in names]
            lines += [f"    if (n_new[{i}] != exp(x[{ln}])) x[{ln}] = log(n_new[{i}]);"]
        lines += ["}", ""]
        return "\n".join(lines)

    # -- fitting support ----------------------------------------------------------------------------

    def fit_form(self) -> LafortuneFitForm:
        return LafortuneFitForm(self)

    def initial_guess(self, f_r, valid, wi, wo):
        """McAllister's start: ρ_d = 10th percentile, lobes at the text's C and n, ρ_s by linear least squares."""
        form = self.fit_form()
        return form.to_model(form.initial_guess(f_r, valid, wi, wo))

    def canonical(self, params):
        """Rescale to C_z = 1 (ρ_s = peak at normal incidence); lobes in C_x + C_y order; β to [−π/4, π/4)
        with C_x ↔ C_y swapped as needed."""
        out = {k: np.array(v, dtype=np.float64, copy=True) for k, v in params.items()}
        for j in range(1, self.lobes + 1):
            cz, n = out[f"c_z_{j}"], out[f"exponent_{j}"]
            scale = np.where(cz > 1e-12, cz, 1.0)  # C_z ≥ 0.05 within the declared bounds
            out[f"rho_s_{j}"] = out[f"rho_s_{j}"] * np.exp(np.clip(n * np.log(scale), -745, 700))
            for nm in (("c_x", "c_y") if self.anisotropic else ("c_xy",)):
                out[f"{nm}_{j}"] = out[f"{nm}_{j}"] / scale
            out[f"c_z_{j}"] = cz / scale
        if self.lobes > 1:  # lobes are interchangeable: order by C_x + C_y (forward-scattering first)
            names = [n for n in out if n.endswith("_1") and not n.startswith("rho_d")]
            key = np.stack([out[f"c_x_{j}"][:, 0] + out[f"c_y_{j}"][:, 0] if self.anisotropic else out[f"c_xy_{j}"][:, 0]
                            for j in range(1, self.lobes + 1)], axis=1)
            order = np.argsort(key, axis=1, kind="stable")  # (T, L)
            for base in (n[:-2] for n in names):
                stack = np.stack([out[f"{base}_{j}"] for j in range(1, self.lobes + 1)], axis=1)  # (T, L, C)
                ordered = np.take_along_axis(stack, order[..., None], axis=1)
                for j in range(1, self.lobes + 1):
                    out[f"{base}_{j}"] = ordered[:, j - 1]
        if self.has_beta:
            b = np.mod(out["beta"] + np.pi / 4, np.pi) - np.pi / 4  # β ≡ β + π, now in [−π/4, 3π/4)
            swap = b >= np.pi / 4
            out["beta"] = np.where(swap, b - np.pi / 2, b)
            for j in range(1, self.lobes + 1):
                cx, cy = out[f"c_x_{j}"].copy(), out[f"c_y_{j}"].copy()
                out[f"c_x_{j}"], out[f"c_y_{j}"] = np.where(swap, cy, cx), np.where(swap, cx, cy)
        return out


    def albedo_bound(self, params):
        """π ρ_d + Σ_j ρ_s,j |C_j|_max^n_j 2π/(n_j + 2), per channel, maximised.

        Seen from ω_i a lobe is max(0, a·ω_o)^n with a = C⊙ω_i, |a| ≤ |C|_max: |a|^n times a cosine lobe about
        â.  Its albedo weights it by cos θ_o, another cosine lobe (about the normal), and the integral of a
        product of two such lobes is largest when they are aligned (Hardy–Littlewood's rearrangement
        inequality on the sphere): ∫ cos^(n+1) θ over the hemisphere = 2π/(n + 2), reached at normal incidence
        by C = (0, 0, 1).  (Until 2026-11-28 the bound dropped the cos θ_o and read 2π/(n + 1): up to 1.5×
        looser at n = 1, so more texels went to the energy check's quadrature.)"""
        a = np.pi * np.asarray(params["rho_d"], np.float64)
        for lobe in self.lobe_list(params):
            n = np.asarray(lobe["exponent"], np.float64)[:, :1]
            cmax = np.max([np.abs(np.asarray(lobe[k], np.float64)[:, :1]) for k in ("c_x", "c_y", "c_z")], axis=0)
            with np.errstate(over="ignore"):
                grow = np.exp(np.minimum(n * np.log(np.maximum(cmax, 1e-300)), 700.0))
            a = a + np.asarray(lobe["rho_s"], np.float64) * grow * 2 * np.pi / (n + 2.0)
        return a.max(axis=1)

    def constrain(self, params, limits):
        """Bound every lobe's peak over the hemisphere and its exponent (:func:`bound_lobes`).

        Works in the C_z = 1 gauge (:meth:`canonical`, the same BRDF), where a
        lobe's largest value up to ``limits.max_theta`` is ρ_s·m^n with
        m = max(1, |C|_max sin²θ + cos²θ): |C_x| or |C_y| above C_z is what
        makes a lobe grow toward grazing.
        """
        out = self.canonical(params) if self.lobes else {k: np.asarray(v, np.float64) for k, v in params.items()}
        out, changed = BRDFModel.constrain(self, out, limits)
        if self.lobes:
            changed |= _apply_lobe_bounds(self, out, limits, exponent_key="exponent_{j}", log=False)
        return out, changed


def bound_lobes(rho_d, lobes, limits):
    """Scale factors that keep C_z = 1 lobes bounded: ``[(rho_scale, c_scale, exponent, dead)], changed``.

    ``lobes`` is ``[(rho_s (T, C), |C|_max (T, 1), n (T, 1))]``.  Each lobe
    gets n ≤ the sharpest the sampling resolves and a shape that grows toward
    grazing by at most ``limits.growth`` (m^n, whatever ρ_s); then, against a
    budget of ``limits.peak − max ρ_d``: ρ_s scaled down if it alone exceeds
    it, |C| shrunk toward 1 until ρ_s·m^n fits (the grazing growth is what the
    samples did not see), and all ρ_s scaled together if the lobes' peaks add
    up to more.  A lobe left below :data:`NEGLIGIBLE` of the budget and of the
    diffuse term is ``dead``: callers reset it to a neutral shape, because an invisible lobe
    parked at |C| = 10 or n = 0.1 turns into a real one when a renderer
    interpolates it with its neighbour's.
    """
    T = rho_d.shape[0]
    changed = np.zeros(T, bool)
    s2, c2 = np.sin(limits.max_theta) ** 2, np.cos(limits.max_theta) ** 2
    n_cap = limits.max_cosine_exponent()
    if limits.peak is None:
        budget = np.full((T, 1), np.inf)
    else:
        budget = np.maximum(np.asarray(limits.peak, np.float64)[:, None] - rho_d.max(axis=1, keepdims=True), 0.0)
    out, peaks = [], []
    with np.errstate(all="ignore"):
        for rho, cabs, n in lobes:
            n_new = np.clip(np.minimum(n, n_cap), *EXPONENT_BOUNDS)
            rmax = rho.max(axis=1, keepdims=True)
            r_scale = np.where(rmax > budget, budget / np.where(rmax > 0, rmax, 1.0), 1.0)
            r = rmax * r_scale
            log_m = np.where((r > 0) & np.isfinite(budget), np.log(budget / np.where(r > 0, r, 1.0)) / n_new, np.inf)
            if limits.growth is not None:
                log_m = np.minimum(log_m, np.log(max(limits.growth, 1.0)) / n_new)
            m_allowed = np.exp(np.minimum(log_m, 50.0))
            c_allowed = np.maximum((m_allowed - c2) / s2, 1.0)
            c_scale = np.where(cabs > c_allowed, c_allowed / np.where(cabs > 0, cabs, 1.0), 1.0)
            m = np.maximum(1.0, cabs * c_scale * s2 + c2)
            peaks.append(r * np.exp(np.minimum(n_new * np.log(m), 700.0)))
            out.append([r_scale, c_scale, n_new])
            changed |= ((n_new < n * (1 - 1e-9)) | (r_scale < 1 - 1e-9) | (c_scale < 1 - 1e-9))[:, 0]
        total = np.sum(peaks, axis=0)
        share = np.where(total > budget, budget / np.where(total > 0, total, 1.0), 1.0)
    changed |= share[:, 0] < 1 - 1e-9
    # Dead: negligible against the budget *and* against the diffuse term.  Why both: a broad weak lobe under a
    # sharp one (peak 0.06 against a budget of 60) is far below the budget yet carries a twentieth of the albedo.
    floor = NEGLIGIBLE * np.minimum(budget, rho_d.max(axis=1, keepdims=True))
    for lobe, peak in zip(out, peaks):
        lobe[0] = lobe[0] * share
        lobe.append(((peak * share) < floor) & np.isfinite(budget))
    return out, changed


def _apply_lobe_bounds(model, out, limits, exponent_key, log, reset_dead=True):
    """:func:`bound_lobes` on ``out`` in place (model form or fit form, C_z = 1); returns ``changed``.

    ``reset_dead`` (model form only) neutralises dead lobes; the fit form
    keeps them as they are: a lobe the iteration is about to grow starts small.
    """
    names = ("c_x", "c_y") if model.anisotropic else ("c_xy",)
    lobes = []
    for j in range(1, model.lobes + 1):
        n = np.asarray(out[exponent_key.format(j=j)], np.float64)
        cabs = np.max([np.abs(out[f"{nm}_{j}"][:, :1]) for nm in names], axis=0)
        lobes.append((out[f"rho_s_{j}"], cabs, np.exp(n) if log else n))
    factors, changed = bound_lobes(out["rho_d"], lobes, limits)
    for j, (r_scale, c_scale, n_new, dead) in enumerate(factors, start=1):
        out[f"rho_s_{j}"] = out[f"rho_s_{j}"] * r_scale
        for nm in names:
            out[f"{nm}_{j}"] = out[f"{nm}_{j}"] * c_scale
        out[exponent_key.format(j=j)] = np.log(n_new) if log else n_new
        if reset_dead:
            neutralise(model, out, j, dead)
    return changed


def neutralise(model, out, j: int, dead: np.ndarray) -> None:
    """Lobe ``j`` of model-form ``out`` reset in place where ``dead`` ``(T, 1)``: ρ_s = 0, C at the text's initial
    lobe, n = :data:`NEUTRAL_EXPONENT`, a shape that stays harmless when quantized or interpolated."""
    if not np.any(dead):
        return
    c0 = INITIAL_LOBES[min(j, 2) - 1][0]
    out[f"rho_s_{j}"] = np.where(dead, 0.0, out[f"rho_s_{j}"])
    out[f"exponent_{j}"] = np.where(dead, NEUTRAL_EXPONENT, out[f"exponent_{j}"])
    for nm in (("c_x", "c_y") if model.anisotropic else ("c_xy",)):
        out[f"{nm}_{j}"] = np.where(dead, c0, out[f"{nm}_{j}"])


def fit_kernel(x, cfg, wi, wo, f, J):
    """f_r and ∂f_r/∂x of the fit form (C_z = 1, log n) at one direction pair: the fitting engine's kernel.

    ``cfg`` = (lobes, anisotropic, beta); ``x`` in :meth:`LafortuneFitForm.pack` order: ρ_d, then per lobe
    ρ_s, C_xy (or C_x, C_y), log n, then β.  The numbers of ``eval`` and ``jacobian`` (their test oracle),
    caps of :func:`~sbrdf_core.brdf.positive_power` included.
    """
    nc, K = f.size, x.size
    lobes, aniso, has_beta = int(cfg[0]), cfg[1] != 0.0, cfg[2] != 0.0
    for c in range(nc):
        f[c] = 0.0
        for k in range(K):
            J[c, k] = 0.0
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return
    ix, iy, ox, oy = wi[0], wi[1], wo[0], wo[1]
    if has_beta:
        cb, sb = math.cos(x[K - 1]), math.sin(x[K - 1])
        ix, iy = cb * wi[0] + sb * wi[1], -sb * wi[0] + cb * wi[1]
        ox, oy = cb * wo[0] + sb * wo[1], -sb * wo[0] + cb * wo[1]
    pxx, pyy, pzz = ix * ox, iy * oy, wi[2] * wo[2]
    for c in range(nc):
        f[c] = x[c]
        J[c, c] = 1.0
    k = nc
    for _ in range(lobes):
        rs = k
        kc = k + nc
        cx = x[kc]
        cy = x[kc + 1] if aniso else cx
        kn = kc + (2 if aniso else 1)
        k = kn + 1
        n = math.exp(x[kn])
        d = cx * pxx + cy * pyy + pzz
        s = dsdx = dsdn = 0.0
        if d > 0.0:
            logd = math.log(d)
            s = math.exp(min(max(n * logd, -745.0), LOG_CAP))
            dsdx = n * math.exp(min(max((n - 1.0) * logd, -745.0), LOG_CAP))
            dsdn = s * logd * n
        for c in range(nc):
            rho = x[rs + c]
            f[c] += rho * s
            J[c, rs + c] = s
            if aniso:
                J[c, kc] = rho * dsdx * pxx
                J[c, kc + 1] = rho * dsdx * pyy
            else:
                J[c, kc] = rho * dsdx * (pxx + pyy)
            J[c, kn] = rho * dsdn
            if has_beta:
                J[c, K - 1] += rho * dsdx * (cx - cy) * (iy * ox + ix * oy)


class LafortuneFitForm(LafortuneModel):
    """The same lobes with C_z = 1 fixed and log n: what fitters iterate on."""

    name = "lafortune-fit-form"

    def __init__(self, model: LafortuneModel):
        self.lobes, self.anisotropic, self.has_beta, self.mirror = model.lobes, model.anisotropic, model.has_beta, model.mirror
        self.channels = model.channels
        self.model = model
        self.parameters = self._declare(fit_form=True)
        self.fit_outlier_ratio = OUTLIER_RATIO if self.lobes >= 2 else None
        self._layout: tuple | None = None  # constrain_packed's bounds and offsets, made on first use

    fit_kernel = staticmethod(fit_kernel)

    def kernel_config(self) -> np.ndarray:
        return np.array([self.lobes, self.anisotropic, self.has_beta], np.float64)

    def lobe_list(self, params):
        out = []
        for j in range(1, self.lobes + 1):
            cx = params[f"c_x_{j}"] if self.anisotropic else params[f"c_xy_{j}"]
            cy = params[f"c_y_{j}"] if self.anisotropic else cx
            out.append({"rho_s": params[f"rho_s_{j}"], "c_x": cx, "c_y": cy, "c_z": np.ones_like(cx),
                        "exponent": np.exp(np.asarray(params[f"log_exponent_{j}"]))})
        return out

    def jacobian(self, params, wi, wo):
        return self._jacobian(params, wi, wo, fit_form=True)

    def fit_trapped(self, x):
        """Rows of a multi-lobe fit where LM lost the forward lobe (:data:`TRAPPED`): a lobe is dead and every live
        lobe scatters backwards (the specular carried by none), or a lobe is a faint spike at the exponent bound,
        fitting a sample or two.  A lobe without magnitude gets no gradient in its shape, so LM cannot bring it back.  A
        dead lobe beside a forward one is not flagged: that is how a 2-lobe fit of one-lobe data ends (GGX data:
        every texel).  McAllister's data (benchmarks/fit.py): 9 of the 11 texels lm2 fitted worse than the peer."""
        if self.lobes < 2:  # one lobe: flagging a backward one cost 25 % of lm's time for 4 texels in 4096
            return np.zeros(x.shape[0], bool)
        p = self.unpack(x)
        dead, faint, spike = TRAPPED
        lobes = range(1, self.lobes + 1)
        peak = np.stack([p[f"rho_s_{j}"].max(axis=1) for j in lobes], axis=1)
        log_n = np.concatenate([p[f"log_exponent_{j}"] for j in lobes], axis=1)
        names = ("c_x", "c_y") if self.anisotropic else ("c_xy",)
        backward = np.stack([np.mean([p[f"{nm}_{j}"][:, 0] for nm in names], axis=0) > 0 for j in lobes], axis=1)
        strongest = peak.max(axis=1, keepdims=True)
        gone = peak <= dead * strongest
        spiked = (peak <= faint * strongest) & (log_n >= np.log(spike * EXPONENT_BOUNDS[1]))
        return (spiked.any(axis=1) | (gone.any(axis=1) & (backward | gone).all(axis=1))) & (strongest[:, 0] > 0)

    def fit_form(self):
        return self

    def limit_box(self, limits, lo, hi):
        """The box part of ``limits`` for the fitting engine: no lobe sharper than the sampling resolves
        (log n ≤ log ``limits.max_cosine_exponent()``); the peak is projected afterwards (:meth:`constrain`)."""
        if limits.resolution is None:
            return lo, hi
        cap = np.log(np.clip(np.asarray(limits.max_cosine_exponent(), np.float64), *EXPONENT_BOUNDS))
        where = self.slices()
        for j in range(1, self.lobes + 1):
            k = where[f"log_exponent_{j}"]
            hi[:, k] = np.minimum(hi[:, k], cap)
        return np.minimum(lo, hi), hi

    def nested(self):
        """Lafortune with one lobe fewer, and its packed fit-form rows embedded here with the last lobe dead
        (ρ_s = 0 at its default shape): what ``lm`` compares a fit with, so a lobe more never fits worse."""
        if self.lobes < 2:
            return None
        smaller = copy.copy(self.model)
        smaller.lobes = self.lobes - 1
        smaller.parameters = smaller._declare(fit_form=False)
        sform = smaller.fit_form()

        def embed(x_small):
            params = sform.unpack(x_small)
            out = self.defaults(x_small.shape[0])
            out.update(params)
            j = self.lobes
            out[f"rho_s_{j}"] = np.zeros_like(out[f"rho_s_{j}"])
            return self.pack(out)

        return smaller, embed

    @property
    def max_step(self) -> np.ndarray:
        """Longest LM step per packed parameter: :data:`MAX_LOG_EXPONENT_STEP` in each log n, the rest unbounded."""
        out = np.full(self.size, np.inf)
        for name, where in self.slices().items():
            if name.startswith("log_exponent_"):
                out[where] = MAX_LOG_EXPONENT_STEP
        return out

    def to_model(self, params):
        """Back to the model's form; a *dead* lobe (ρ_s below DEAD_LOBE) is reset to a harmless shape.

        A fit may park an unneeded lobe at ρ_s ≈ 1e-29 with |C| = 10 and
        n = 20000: invisible at the sampled directions, but at grazing angles
        |C·ω|^n explodes, and any quantization of ρ_s turns it into 1e18 sr⁻¹.
        """
        out = {k: np.asarray(v) for k, v in params.items() if not k.startswith("log_exponent_")}
        for j in range(1, self.lobes + 1):
            out[f"c_z_{j}"] = np.ones_like(np.asarray(params[f"log_exponent_{j}"]))
            out[f"exponent_{j}"] = np.exp(np.asarray(params[f"log_exponent_{j}"]))
            neutralise(self, out, j, np.asarray(params[f"rho_s_{j}"]).max(axis=1, keepdims=True) < DEAD_LOBE)
        if self.has_beta:
            out["beta"] = np.mod(np.asarray(params["beta"]) + np.pi / 2, np.pi) - np.pi / 2
        if self.mirror:
            out["rho_m"] = np.zeros_like(np.asarray(params["rho_d"]))
        return out

    def from_model(self, params):
        canon = self.model.canonical(params)
        out = {k: v for k, v in canon.items() if not (k.startswith("c_z_") or k.startswith("exponent_") or k == "rho_m")}
        for j in range(1, self.lobes + 1):
            out[f"log_exponent_{j}"] = np.log(np.clip(canon[f"exponent_{j}"], *EXPONENT_BOUNDS))
            for nm in (("c_x", "c_y") if self.anisotropic else ("c_xy",)):
                out[f"{nm}_{j}"] = np.clip(out[f"{nm}_{j}"], *FIT_C_BOUNDS)
        return out

    def initial_guess(self, f_r, valid, wi, wo):
        """ρ_d the 10th percentile of the samples (seed 000 §4.3); lobe 1's exponent the best of
        :data:`START_EXPONENTS` for the texel (the text's n = 10 among them), each scored with the lobes'
        magnitudes solved: every texel starts near its own sharpness, which saves LM iterations."""
        from sbrdf_lib.lm import least_squares

        T = f_r.shape[0]
        params = self.defaults(T)
        from sbrdf_lib.lm import diffuse_percentile  # the solver library, needed only when a fit starts

        params["rho_d"] = diffuse_percentile(f_r, valid, 10.0)
        if not self.lobes:
            return params
        objective = least_squares(self, f_r, np.asarray(valid, np.float64), wi, wo)
        lo, hi = self.bounds()
        best = best_cost = None
        for log_n in np.log(START_EXPONENTS):
            guess = self.refine_linear({**params, "log_exponent_1": np.full((T, 1), log_n)}, f_r, valid, wi, wo)
            x = np.clip(self.pack(guess), lo, hi)
            cost = np.nan_to_num(objective.cost(x, np.arange(T)), nan=np.inf)
            if best is None:
                best, best_cost = x, cost
            else:
                better = cost < best_cost
                best[better], best_cost[better] = x[better], cost[better]
        return self.unpack(best)

    def refine_linear(self, params, f_r, valid, wi, wo):
        return {**params, **solve_magnitudes(self, params, f_r, valid, wi, wo)} if self.lobes else dict(params)

    def constrain_packed(self, x, limits):
        """:meth:`constrain` on packed rows ``x`` ``(T, K)``, compiled (``lafortune_kernels.constrain_packed``): what
        LM projects every trial point with.  Falls back to :meth:`constrain` where the horizon bound is 0° (the
        NumPy path's division by sin² θ = 0 is not reproduced)."""
        args = self.packed_limits(limits, x.shape[0])
        if args is None:
            return self.pack(self.constrain(self.unpack(x), limits)[0])
        from .lafortune_kernels import constrain_packed

        lo, hi, peak, has_peak, n_cap, growth, s2, c2, n_lo, n_hi, rho_at, c_at, ln_at = args
        return constrain_packed(np.ascontiguousarray(x, np.float64), lo, hi, peak, has_peak, n_cap, growth, s2, c2,
                                n_lo, n_hi, rho_at, c_at, ln_at, self.channels)

    def packed_limits(self, limits, T: int) -> tuple | None:
        """What the compiled projection (``lafortune_kernels._project_row``) reads for ``T`` texels: ``(lo, hi,
        peak (T,), has_peak, n_cap (T,), growth (< 0: off), sin² θ_max, cos² θ_max, n bounds, and the packed
        offsets of each lobe's ρ_s, C and log n)``; ``limits`` None: every bound off.  None where the compiled
        projection does not apply: no lobes, or a horizon bound of 0° (the NumPy path's division by sin² θ = 0
        is not reproduced)."""
        max_theta = np.pi / 2 if limits is None else limits.max_theta
        s2, c2 = float(np.sin(max_theta) ** 2), float(np.cos(max_theta) ** 2)
        if s2 == 0.0 or not self.lobes:
            return None
        if self._layout is None:  # the packed bounds and offsets, once per form
            sl, lobes = self.slices(), range(1, self.lobes + 1)
            names = ("c_x", "c_y") if self.anisotropic else ("c_xy",)
            self._layout = (*self.bounds(), *map(float, EXPONENT_BOUNDS),
                            np.array([sl[f"rho_s_{j}"].start for j in lobes], np.int64),
                            np.array([[sl[f"{nm}_{j}"].start for nm in names] for j in lobes], np.int64),
                            np.array([sl[f"log_exponent_{j}"].start for j in lobes], np.int64))
        lo, hi, n_lo, n_hi, rho_at, c_at, ln_at = self._layout
        if limits is None:
            return lo, hi, np.zeros(T), False, np.full(T, np.inf), -1.0, s2, c2, n_lo, n_hi, rho_at, c_at, ln_at
        n_cap = np.broadcast_to(np.asarray(limits.max_cosine_exponent(), np.float64).reshape(-1), (T,))
        peak = np.zeros(T) if limits.peak is None else np.asarray(limits.peak, np.float64).reshape(T)
        return (lo, hi, np.ascontiguousarray(peak), limits.peak is not None, np.ascontiguousarray(n_cap),
                -1.0 if limits.growth is None else float(limits.growth), s2, c2, n_lo, n_hi, rho_at, c_at, ln_at)

    def constrain(self, params, limits):
        """:func:`bound_lobes` directly on the fit form (C_z = 1 already, log n)."""
        out, changed = BRDFModel.constrain(self, params, limits)
        if self.lobes:
            changed |= _apply_lobe_bounds(self, out, limits, exponent_key="log_exponent_{j}", log=True,
                                          reset_dead=False)
        return out, changed

    def random_guess(self, rng, T):
        params = super().random_guess(rng, T)
        if self.has_beta:
            params["beta"] = rng.uniform(-np.pi / 2, np.pi / 2, (T, 1))
        return params


def solve_magnitudes(model: LafortuneModel, params, f_r, valid, wi, wo) -> dict[str, np.ndarray]:
    """ρ_s per lobe by non-negative-clipped linear least squares on ``f_r − ρ_d`` with lobe shapes fixed."""
    pxx, pyy, pzz, _ = model.lobe_dots(params, wi, wo)
    w = (valid & above_horizon(wi, wo)).astype(float)
    basis = []
    for lobe in model.lobe_list(params):
        x = lobe["c_x"][:, :1] * pxx + lobe["c_y"][:, :1] * pyy + lobe["c_z"][:, :1] * pzz
        basis.append(positive_power(x, lobe["exponent"][:, :1]) * w)
    B = np.stack(basis, axis=-1)  # (T, S, L)
    resid = np.where(w[..., None] > 0, f_r - params["rho_d"][:, None, :], 0.0)
    A = B.transpose(0, 2, 1) @ B + 1e-12 * np.eye(B.shape[-1])
    rhs = B.transpose(0, 2, 1) @ resid  # (T, L, 3)
    rho = np.clip(np.linalg.solve(A, rhs), 0.0, 1e6)
    rho = np.nan_to_num(rho, nan=0.0, posinf=0.0)
    return {f"rho_s_{j + 1}": rho[:, j, :] for j in range(B.shape[-1])}


@hookimpl
def sbrdf_brdf_models():
    return [PluginSpec("lafortune", "sbrdf_models.lafortune:LafortuneModel",
                       summary="Generalized cosine lobes (McAllister's SBRDF): rho_d + sum rho_s max(0, w_r C w_i)^n")]
