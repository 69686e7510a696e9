"""ggx-anisotropic: the anisotropic GGX lobe of glTF's ``KHR_materials_anisotropy``, with a per-texel direction.

Interchange formats carry anisotropy as one GGX lobe whose roughness differs
along a direction in the surface: glTF's ``KHR_materials_anisotropy`` (and
OpenPBR, MaterialX and USD the same way).  An anisotropic fit (Lafortune with
``anisotropic``/``beta``, anisotropic Ward) is exported by refitting it to this
model (:mod:`sbrdf_lib.convert`), and a glTF read back renders through it.

    f_r(ω_i, ω_o) = ρ_d + F(ω_i·h) D(h) V(ω_i, ω_o),    h = (ω_i + ω_o)/|ω_i + ω_o|

in the frame rotated about the normal by ``phi`` (x' along the anisotropy
direction, the glTF tangent-space direction (cos φ, sin φ)):

- D = 1 / (π α_t α_b ((h_x'/α_t)² + (h_y'/α_b)² + h_z²)²)
- V = G/(4 cos θ_i cos θ_o) = ½ / (cos θ_o |(α_t ω_ix', α_b ω_iy', cos θ_i)| + cos θ_i |(α_t ω_ox', α_b ω_oy', cos θ_o)|),
  the height-correlated Smith term with anisotropic Λ (Heitz 2014), exactly the
  extension's ``V_GGX_anisotropic``
- F = F0 + (1 − F0)(1 − ω_i·h)⁵ per RGB channel

With α_t = α_b it is ``cook-torrance`` with ``distribution: ggx``.  glTF
reads ``alpha_b = roughness²`` and ``alpha_t = mix(roughness², 1, strength²)``,
so it needs α_t ≥ α_b: :meth:`canonical` swaps the axes (φ + π/2) to make it
so.  Grazing: cosines floored at :data:`COS_FLOOR`, so f stays finite.  The fit
form fits log α_t, log α_b.

YAML::

    fit: {kind: Fit, plugin: lm, in: {samples: reflectance}, params: {model: ggx-anisotropic}}
"""

from __future__ import annotations

import math

import numpy as np

from sbrdf_core.brdf import BRDFModel, LogFitForm, ModelParameter, above_horizon
from sbrdf_core.constraints import WidenedRoughness

from .cook_torrance import schlick_lobe, schlick_lobe_jacobian

COS_FLOOR = 1e-6
ALPHA_BOUNDS = (1e-3, 1.0)


def fit_kernel(x, cfg, wi, wo, f, J):
    """f_r and ∂f_r/∂x in the fit form x = (ρ_d, F0, log α_t, log α_b, φ) at one direction pair; zeros below the
    horizon.  The floors and the derivatives of log D and of the Smith roots are :meth:`GGXAnisotropicModel._terms`'."""
    for c in range(3):
        f[c] = 0.0
        for k in range(9):
            J[c, k] = 0.0
    if not (wi[2] > 0.0 and wo[2] > 0.0):  # not ≤ 0: NaN directions give 0, as above_horizon does
        return
    at, ab, phi = math.exp(x[6]), math.exp(x[7]), x[8]
    cp, sp = math.cos(phi), math.sin(phi)
    ci, co = max(wi[2], COS_FLOOR), max(wo[2], COS_FLOOR)
    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    hl = math.sqrt(max(hx * hx + hy * hy + hz * hz, 1e-300))
    hx, hy, hz = hx / hl, hy / hl, hz / hl
    hxr, hyr = cp * hx + sp * hy, -sp * hx + cp * hy  # in the anisotropy frame
    hzf = max(hz, COS_FLOOR)
    q = max((hxr / at) ** 2 + (hyr / ab) ** 2 + hzf * hzf, 1e-300)
    D = 1.0 / (math.pi * at * ab * q * q)
    dlnD_t = -1.0 / at + 4.0 * hxr**2 / (q * at**3)
    dlnD_b = -1.0 / ab + 4.0 * hyr**2 / (q * ab**3)
    dlnD_phi = -4.0 * hxr * hyr * (1.0 / at**2 - 1.0 / ab**2) / q
    # Smith roots |(α_t ω_x', α_b ω_y', cos θ)| / cos θ of ω_i and ω_o, and their derivatives by α_t, α_b, φ
    rsum, dr_t, dr_b, dr_phi = 0.0, 0.0, 0.0, 0.0
    for j in range(2):
        w = wi if j == 0 else wo
        cz = ci if j == 0 else co
        wx, wy = cp * w[0] + sp * w[1], -sp * w[0] + cp * w[1]
        r = math.sqrt(1.0 + (at * at * wx * wx + ab * ab * wy * wy) / (cz * cz))
        rsum += r
        dr_t += at * wx * wx / (cz * cz * r)
        dr_b += ab * wy * wy / (cz * cz * r)
        dr_phi += wx * wy * (at * at - ab * ab) / (cz * cz * r)
    V = 0.5 / (ci * co * rsum)
    spec = D * V
    dspec_t = spec * (dlnD_t - dr_t / rsum)
    dspec_b = spec * (dlnD_b - dr_b / rsum)
    dspec_phi = spec * (dlnD_phi - dr_phi / rsum)
    cos_d = min(max(wi[0] * hx + wi[1] * hy + wi[2] * hz, 0.0), 1.0)
    schlick = (1.0 - cos_d) ** 5
    for c in range(3):
        F = x[3 + c] + (1.0 - x[3 + c]) * schlick
        f[c] = x[c] + F * spec
        J[c, c] = 1.0
        J[c, 3 + c] = spec * (1.0 - schlick)
        J[c, 6] = F * dspec_t * at
        J[c, 7] = F * dspec_b * ab
        J[c, 8] = F * dspec_phi


class GGXAnisotropicModel(WidenedRoughness, BRDFModel):
    name = "ggx-anisotropic"
    #: What the sampling bounds (``LogFitForm.limit_box``): the sharpness the samples resolve.
    roughness = ("alpha_t", "alpha_b")
    anisotropic = True
    fit_kernel = staticmethod(fit_kernel)
    parameters = (
        ModelParameter("rho_d", 3, (0.0, 10.0), (0.02, 0.25), 0.1, unit="sr^-1", doc="diffuse term", magnitude=True),
        ModelParameter("f0", 3, (0.0, 1.0), (0.02, 0.9), 0.04, unit="1", doc="Fresnel reflectance at normal incidence",
                       magnitude=True),
        ModelParameter("alpha_t", 1, ALPHA_BOUNDS, (0.05, 0.5), 0.2, doc="GGX roughness along the anisotropy direction"),
        ModelParameter("alpha_b", 1, ALPHA_BOUNDS, (0.05, 0.5), 0.2, doc="GGX roughness across the anisotropy direction"),
        ModelParameter("phi", 1, (-np.pi, np.pi), (-np.pi / 2, np.pi / 2), 0.0, unit="rad",
                       doc="anisotropy direction: rotation from the tangent (x) about the normal"),
    )

    def _terms(self, params, wi, wo):
        """spec = D·V, its derivatives by (α_t, α_b, φ) as (T, S, 3), and the Schlick weight (1 − ω_i·h)⁵."""
        at = np.asarray(params["alpha_t"])[:, :1]
        ab = np.asarray(params["alpha_b"])[:, :1]
        phi = np.asarray(params["phi"])[:, :1]
        c, s = np.cos(phi), np.sin(phi)

        def rotate(w):
            return c * w[..., 0] + s * w[..., 1], -s * w[..., 0] + c * w[..., 1]

        up = above_horizon(wi, wo)
        ci = np.maximum(wi[..., 2], COS_FLOOR)
        co = np.maximum(wo[..., 2], COS_FLOOR)
        h = wi + wo
        hn = h / np.sqrt(np.maximum(np.einsum("tsk,tsk->ts", h, h), 1e-300))[..., None]
        hx, hy = rotate(hn)
        hz = np.maximum(hn[..., 2], COS_FLOOR)
        q = np.maximum((hx / at) ** 2 + (hy / ab) ** 2 + hz * hz, 1e-300)
        D = 1.0 / (np.pi * at * ab * q * q)
        dlnD = (-1.0 / at + 4.0 * hx**2 / (q * at**3), -1.0 / ab + 4.0 * hy**2 / (q * ab**3),
                -4.0 * hx * hy * (1.0 / at**2 - 1.0 / ab**2) / q)
        root, droot = [], []
        for w, cz in ((wi, ci), (wo, co)):
            x, y = rotate(w)
            r = np.sqrt(1.0 + (at * at * x * x + ab * ab * y * y) / (cz * cz))
            root.append(r)
            droot.append((at * x * x / (cz * cz * r), ab * y * y / (cz * cz * r), x * y * (at * at - ab * ab) / (cz * cz * r)))
        rsum = root[0] + root[1]
        V = 0.5 / (ci * co * rsum)
        spec = np.where(up, D * V, 0.0)
        dspec = np.stack([spec * (dlnD[k] - (droot[0][k] + droot[1][k]) / rsum) for k in range(3)], axis=-1)
        cos_d = np.clip(np.einsum("tsk,tsk->ts", wi, hn), 0.0, 1.0)
        return spec, dspec, (1.0 - cos_d) ** 5

    def eval(self, params, wi, wo):
        spec, _, schlick = self._terms(params, wi, wo)
        return schlick_lobe(params, wi, wo, spec, schlick)

    def jacobian(self, params, wi, wo):
        spec, dspec, schlick = self._terms(params, wi, wo)
        return schlick_lobe_jacobian(params, wi, wo, spec, dspec, schlick)

    def glsl(self) -> str:
        """``vec3 brdf_ggx_anisotropic(wi, wo, rho_d, f0, alpha_t, alpha_b, phi)`` in the surface frame."""
        return (
            "vec3 brdf_ggx_anisotropic(vec3 wi, vec3 wo, vec3 rho_d, vec3 f0, float alpha_t, float alpha_b, float phi) {\n"
            "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
            "    float c = cos(phi), s = sin(phi);\n"
            "    float ci = max(wi.z, 1e-6), co = max(wo.z, 1e-6);\n"
            "    vec3 h = normalize(wi + wo);\n"
            "    vec2 hr = vec2(c * h.x + s * h.y, -s * h.x + c * h.y) / vec2(alpha_t, alpha_b);\n"
            "    float q = max(dot(hr, hr) + h.z * h.z, 1e-30);\n"
            "    float D = 1.0 / (3.14159265359 * alpha_t * alpha_b * q * q);\n"
            "    vec2 ir = vec2(c * wi.x + s * wi.y, -s * wi.x + c * wi.y) * vec2(alpha_t, alpha_b);\n"
            "    vec2 orr = vec2(c * wo.x + s * wo.y, -s * wo.x + c * wo.y) * vec2(alpha_t, alpha_b);\n"
            "    float V = 0.5 / (co * length(vec3(ir, ci)) + ci * length(vec3(orr, co)));\n"
            "    vec3 F = f0 + (1.0 - f0) * pow(1.0 - clamp(dot(wi, h), 0.0, 1.0), 5.0);\n"
            "    return rho_d + F * (D * V);\n"
            "}\n"
        )

    def fit_form(self) -> LogFitForm:
        return LogFitForm(self, ("alpha_t", "alpha_b"))

    def canonical(self, params):
        """α_t ≥ α_b (glTF's reading: the direction is the rougher axis) and φ in [−π/2, π/2)."""
        out = {k: np.asarray(v, np.float64).copy() for k, v in params.items()}
        swap = out["alpha_t"] < out["alpha_b"]
        out["alpha_t"], out["alpha_b"] = np.where(swap, out["alpha_b"], out["alpha_t"]), np.where(swap, out["alpha_t"],
                                                                                                   out["alpha_b"])
        phi = out["phi"] + np.where(swap, np.pi / 2, 0.0)
        out["phi"] = np.mod(phi + np.pi / 2, np.pi) - np.pi / 2
        return out
