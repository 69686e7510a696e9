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
from typing import TYPE_CHECKING

import numpy as np

from sbrdf_core.brdf import BRDFModel, ModelParameter, above_horizon, positive_power
from sbrdf_core.constraints_glsl import BIG, clip_lines, glsl_float, max_cosine_exponent

from . import declarations

if TYPE_CHECKING:
    from .lafortune_fit import LafortuneFitForm

from .lafortune_bounds import EXPONENT_BOUNDS, INITIAL_LOBES, _apply_lobe_bounds

#: A lobe whose ρ_s (every channel) is below this, sr⁻¹, contributes nothing measurable: see to_model.
DEAD_LOBE = 1e-9
#: A lobe LM has lost (``fit_trapped``): dead, its peak ρ_s at most the first fraction of the strongest lobe's; or a
#: spike on a sample or two, at most the second fraction with n within the last factor of its bound.
TRAPPED = (1e-3, 0.1, 0.95)
#: A multi-lobe texel whose cost per sample is over this multiple of its tile's median is fitted again
#: (``fit_outlier_ratio``): on benchmarks/fit.py's Lafortune data, 2 lobes, 10 of 1024 texels settled with two lobes
#: on the mirror peak or one at n ≈ 20000 and fitted 3-8x worse than the peer; one lobe: not worth its time (the
#: missing lobe's energy varies texel to texel, so a third of a tile are "outliers" a restart cannot improve).
OUTLIER_RATIO = 2.0
#: Longest LM step in a lobe's log n (the fit form's ``max_step``): n changes by at most e^0.5 ≈ 1.65× a step.
#: Why: unbounded, a Gauss–Newton step could multiply n several times over, cost more than the start, and leave
#: λ to grow through many evaluations until the step was short enough.
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

    params = declarations.LAFORTUNE

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
        from .lafortune_fit import LafortuneFitForm

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
        by C = (0, 0, 1)."""
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
