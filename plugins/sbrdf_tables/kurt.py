"""kurt-transmissive: Kurt et al.'s anisotropic Beckmann lobes with thin-slab transmission (seed 004 §3.3).

Mühlbacher fits this BSDF to gonioreflectometer tables because its lobes are
normalised microfacet lobes (so k_s reads as a reflectivity), anisotropic
(brushed metals) and carry Schlick Fresnel plus Kurt's α exponent, which
brightens towards grazing the way varnished and polished surfaces do:

    f_s = k_d/π + Σ_j k_s_j f_r_lobe_j(ω_i, ω_o)      (ω_o above the surface, Eq 3.2/3.4)
                + Σ_j k_t_j f_t_lobe_j(ω_i, ω_o)      (ω_o below: transmission, Eq 3.5/3.6)

    D(h) = exp(−tan²θ_h (cos²ϕ_h/m_x² + sin²ϕ_h/m_y²)) / (π m_x m_y cos⁴θ_h)           (Eq 3.3)
    f_r_lobe = F(ω_o·h) D(h) / (4 (ω_o·h) (cos θ_i cos θ_o)^α),  F(u) = r_0 + (1 − r_0)(1 − u)⁵
    f_t_lobe = the same lobe on the mirrored configuration ω'_o = ω_o reflected by the surface plane,
               with 1 − F instead of F: thin slab, principal transmission direction ω_t = −ω_i.

The α term uses |cos θ_i|·|cos θ_o| (notes §10.2: the printed second form of
Eq 3.5 has a sign typo).  With transmission lobes the slab is two-sided: light
arriving from below (ω_i·n < 0) is handled by mirroring both directions, so a
renderer can light a pane from behind (without them the model is an opaque
BRDF, zero below the horizon as the contract asks); k_d/π is reflection only
(the thesis has no diffuse BTDF).

Finite everywhere: cosines, cos θ_h and ω_o·h are floored at :data:`COS_FLOOR`
and the Beckmann exponent is capped, so grazing and exactly-horizontal
directions give large but finite values, never NaN.  ``k_d``, ``k_s``, ``k_t``
are RGB (3 channels; a single-channel table gives equal channels); the lobe
shape (m_x, m_y, r_0, α) is shared by the channels.  The fit form fits log m.
The per-texel maps: ``k_d``; per reflection lobe j ``k_s_j``, ``m_x_j``,
``m_y_j`` (Beckmann roughness along tangent / bitangent), ``r_0_j`` (Schlick
reflectance at normal incidence), ``alpha_j`` (Kurt's shadowing exponent);
per transmission lobe ``k_t_j`` and the same shape names with ``t_``.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.brdf import BRDFModel, LogFitForm, ModelParameter

from .declarations import KURT

#: Floor on cosines and on ω_o·h: keeps 1/(ω_o·h) and (cos θ_i cos θ_o)^-α finite at the horizon.
COS_FLOOR = 1e-6
#: Roughness bounds: below 1e-4 the lobe is narrower than any gonioreflectometer resolves.
M_BOUNDS = (1e-4, 2.0)
#: Largest Beckmann exponent evaluated (exp(-700) is already 0 in float64 terms that matter).
EXPONENT_CAP = 700.0


def lobe_geometry(wi: np.ndarray, wo: np.ndarray, transmission: bool, two_sided: bool = False) -> dict[str, np.ndarray]:
    """The direction-only terms of one lobe, broadcastable over any leading shape.

    Returns ``x2 = (h_x/h_z)²``, ``y2 = (h_y/h_z)²``, ``hz4 = cos⁴θ_h``, ``cos_d = ω_o·h``,
    ``cc = |cos θ_i cos θ_o|`` and ``side``: where this lobe applies (reflection: both
    directions above; transmission: ω_i above, ω_o below).  ``two_sided`` (a thin slab)
    first mirrors both directions when ω_i is below; transmission then mirrors ω_o.
    The grid-search fitter reuses these to evaluate n^P candidates by outer products.
    """
    if two_sided:
        flip = np.where(wi[..., 2:3] < 0, np.array([1.0, 1.0, -1.0]), 1.0)
        wi, wo = wi * flip, wo * flip
    if transmission:
        side = (wi[..., 2] > 0) & (wo[..., 2] < 0)
        wo = wo * np.array([1.0, 1.0, -1.0])
    else:
        side = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    ci = np.maximum(wi[..., 2], COS_FLOOR)
    co = np.maximum(wo[..., 2], COS_FLOOR)
    h = wi + wo
    norm = np.sqrt(np.maximum(np.einsum("...k,...k->...", h, h), 1e-300))
    h = h / norm[..., None]
    hz = np.maximum(h[..., 2], COS_FLOOR)
    return {
        "x2": (h[..., 0] / hz) ** 2, "y2": (h[..., 1] / hz) ** 2, "hz4": hz**4,
        "cos_d": np.clip(np.einsum("...k,...k->...", wo, h), COS_FLOOR, 1.0), "cc": ci * co, "side": side,
    }


def beckmann(g, m_x, m_y):
    """Anisotropic normalised Beckmann D(h) (Eq 3.3) from :func:`lobe_geometry` terms."""
    e = np.minimum(g["x2"] / (m_x * m_x) + g["y2"] / (m_y * m_y), EXPONENT_CAP)
    return np.exp(-e) / (np.pi * m_x * m_y * g["hz4"])


def schlick(cos_d, r_0):
    """Schlick's Fresnel approximation (Eq 2.9): F(1) = r_0, F(0) = 1."""
    return r_0 + (1.0 - r_0) * (1.0 - cos_d) ** 5


def lobe(g, m_x, m_y, r_0, alpha, transmission: bool):
    """f_r_lobe (Eq 3.4) or f_t_lobe (Eq 3.5) without its k coefficient; 0 where the lobe does not apply."""
    F = schlick(g["cos_d"], r_0)
    if transmission:
        F = 1.0 - F
    f = F * beckmann(g, m_x, m_y) / (4.0 * g["cos_d"] * g["cc"] ** alpha)
    return np.where(g["side"], f, 0.0)


class KurtTransmissiveModel(BRDFModel):
    name = "kurt-transmissive"

    params = KURT

    def __init__(self, *, lobes: int = 1, transmission_lobes: int = 0):
        if lobes < 0 or transmission_lobes < 0:
            raise ValueError("kurt-transmissive: lobe counts must be >= 0")
        self.lobes, self.transmission_lobes = int(lobes), int(transmission_lobes)
        #: A pane that transmits is lit from either side; an opaque reflector is zero below its horizon.
        self.two_sided = self.transmission_lobes > 0
        params = [ModelParameter("k_d", 3, (0.0, 1.0), (0.0, 0.8), 0.1, unit="1", doc="diffuse albedo, f = k_d/π")]
        for kind, count in (("", self.lobes), ("t_", self.transmission_lobes)):
            coefficient = "k_t" if kind else "k_s"
            for j in range(1, count + 1):
                params += [
                    ModelParameter(f"{coefficient}_{j}", 3, (0.0, 1.0), (0.1, 1.0), 0.5, unit="1",
                                   doc=f"{'transmission' if kind else 'reflection'} lobe {j} coefficient"),
                    ModelParameter(f"m_x_{kind}{j}", 1, M_BOUNDS, (0.02, 0.4), 0.1, doc="roughness along tangent"),
                    ModelParameter(f"m_y_{kind}{j}", 1, M_BOUNDS, (0.02, 0.4), 0.1, doc="roughness along bitangent"),
                    ModelParameter(f"r_0_{kind}{j}", 1, (0.0, 1.0), (0.02, 0.95), 0.5, doc="Schlick r_0"),
                    ModelParameter(f"alpha_{kind}{j}", 1, (0.0, 1.0), (0.0, 0.7), 0.4, doc="Kurt's α exponent"),
                ]
        self.parameters = tuple(params)

    def lobe_names(self):
        """``(coefficient, m_x, m_y, r_0, alpha, transmission)`` parameter names of every lobe."""
        out = []
        for kind, coefficient, count in (("", "k_s", self.lobes), ("t_", "k_t", self.transmission_lobes)):
            for j in range(1, count + 1):
                out.append((f"{coefficient}_{j}", f"m_x_{kind}{j}", f"m_y_{kind}{j}", f"r_0_{kind}{j}",
                            f"alpha_{kind}{j}", bool(kind)))
        return out

    def eval(self, params, wi, wo):
        p = {k: np.asarray(v, dtype=np.float64) for k, v in params.items()}
        geometry = {t: lobe_geometry(wi, wo, t, self.two_sided) for t in (False, True)}
        reflect = geometry[False]["side"]
        f = np.where(reflect[..., None], p["k_d"][:, None, :] / np.pi, 0.0)
        for k, mx, my, r0, a, t in self.lobe_names():
            shape = lobe(geometry[t], p[mx][:, :1], p[my][:, :1], p[r0][:, :1], p[a][:, :1], t)
            f = f + p[k][:, None, :] * shape[..., None]
        return f

    def jacobian(self, params, wi, wo):
        """Analytic ``∂f/∂x`` ``(T, S, 3, K)``: every lobe factor is a product, so each column is f_lobe × ∂ln(factor).

        ∂ln D/∂m_x = 2 tan²θ_h cos²ϕ_h / m_x³ − 1/m_x (0 where the exponent is capped),
        ∂ln(cc^−α)/∂α = −ln(cos θ_i cos θ_o), ∂F/∂r_0 = 1 − (1 − u)⁵ (negated for 1 − F).
        """
        p = {k: np.asarray(v, dtype=np.float64) for k, v in params.items()}
        geometry = {t: lobe_geometry(wi, wo, t, self.two_sided) for t in (False, True)}
        slices = self.slices()
        T, S = wi.shape[:2]
        J = np.zeros((T, S, 3, self.size))
        reflect = geometry[False]["side"].astype(float)
        for c in range(3):
            J[:, :, c, slices["k_d"].start + c] = reflect / np.pi
        for k, mx, my, r0, a, t in self.lobe_names():
            g = geometry[t]
            m_x, m_y, r_0, alpha = (p[n][:, :1] for n in (mx, my, r0, a))
            coefficient = p[k][:, None, :]  # (T, 1, 3)
            D = beckmann(g, m_x, m_y)
            capped = g["x2"] / (m_x * m_x) + g["y2"] / (m_y * m_y) >= EXPONENT_CAP
            A = np.where(g["side"], 1.0 / (4.0 * g["cos_d"] * g["cc"] ** alpha), 0.0)
            schlick_term = 1.0 - (1.0 - g["cos_d"]) ** 5
            F = r_0 + (1.0 - r_0) * (1.0 - g["cos_d"]) ** 5
            if t:
                F, schlick_term = 1.0 - F, -schlick_term
            shape = F * D * A
            for c in range(3):
                J[:, :, c, slices[k].start + c] = shape
            dlnD_x = np.where(capped, 0.0, 2.0 * g["x2"] / m_x**3) - 1.0 / m_x
            dlnD_y = np.where(capped, 0.0, 2.0 * g["y2"] / m_y**3) - 1.0 / m_y
            J[..., slices[mx].start] = coefficient * (shape * dlnD_x)[..., None]
            J[..., slices[my].start] = coefficient * (shape * dlnD_y)[..., None]
            J[..., slices[r0].start] = coefficient * (schlick_term * D * A)[..., None]
            J[..., slices[a].start] = coefficient * (-shape * np.log(g["cc"]))[..., None]
        return J

    def glsl(self) -> str:
        """``vec3 brdf_kurt_transmissive(wi, wo, k_d, k_s_1, m_x_1, …)``: the declared parameters in order (the
        renderers' convention, vec3 for RGB), plus a ``kurt_lobe`` helper; surface frame."""
        lines = [
            "float kurt_lobe(vec3 wi, vec3 wo, float mx, float my, float r0, float alpha, bool transmission) {",
            "    if (wi.z <= 0.0) return 0.0;",
            "    if (transmission) { if (wo.z >= 0.0) return 0.0; wo.z = -wo.z; } else if (wo.z <= 0.0) return 0.0;",
            "    vec3 h = normalize(wi + wo);",
            "    float hz = max(h.z, 1e-6);",
            "    float e = min((h.x*h.x/(hz*hz))/(mx*mx) + (h.y*h.y/(hz*hz))/(my*my), 700.0);",
            "    float D = exp(-e) / (3.14159265359 * mx * my * hz*hz*hz*hz);",
            "    float cd = clamp(dot(wo, h), 1e-6, 1.0);",
            "    float F = r0 + (1.0 - r0) * pow(1.0 - cd, 5.0);",
            "    if (transmission) F = 1.0 - F;",
            "    float cc = max(wi.z, 1e-6) * max(wo.z, 1e-6);",
            "    return F * D / (4.0 * cd * pow(cc, alpha));",
            "}",
            "vec3 brdf_kurt_transmissive(vec3 wi, vec3 wo, "
            + ", ".join(("vec3 " if q.channels == 3 else "float ") + q.name for q in self.parameters) + ") {",
        ]
        if self.two_sided:
            lines.append("    if (wi.z < 0.0) { wi.z = -wi.z; wo.z = -wo.z; }")
        lines.append("    vec3 f = (wi.z > 0.0 && wo.z > 0.0) ? k_d / 3.14159265359 : vec3(0.0);")
        for k, mx, my, r0, a, t in self.lobe_names():
            lines.append(f"    f += {k} * kurt_lobe(wi, wo, {mx}, {my}, {r0}, {a}, {'true' if t else 'false'});")
        lines += ["    return f;", "}"]
        return "\n".join(lines) + "\n"

    def fit_form(self):
        names = [n for lobe_ in self.lobe_names() for n in lobe_[1:3]]
        return LogFitForm(self, names)

    def canonical(self, params):
        """Lobes of each hemisphere in order of increasing m_x·m_y (narrowest first), so fits compare lobe by lobe.

        Lobes are interchangeable terms of a sum; the alternating fitter finds them in either order.
        """
        out = {k: np.asarray(v, dtype=np.float64).copy() for k, v in params.items()}
        for transmission in (False, True):
            lobes = [lb for lb in self.lobe_names() if lb[5] == transmission]
            if len(lobes) < 2:
                continue
            width = np.stack([np.asarray(params[lb[1]])[:, 0] * np.asarray(params[lb[2]])[:, 0] for lb in lobes], 1)
            order = np.argsort(width, axis=1, kind="stable")  # (T, L)
            for field in range(5):
                stacked = np.stack([np.asarray(params[lb[field]], dtype=np.float64) for lb in lobes], 1)  # (T, L, C)
                ordered = np.take_along_axis(stacked, order[:, :, None], axis=1)
                for j, lb in enumerate(lobes):
                    out[lb[field]] = ordered[:, j]
        return out
