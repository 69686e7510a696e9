"""velvet: Ashikhmin & Premože's distribution-based velvet, the "deep microgeometry" test BRDF of seed 001 §5.2.

Seed 001 finds velvet (fibres standing up from the surface, self-shadowing,
a sheen that brightens toward grazing) most separable in the standard
incident/view parameterization, unlike microfacet BRDFs.  Its measured
velvet is not available; this analytic stand-in has the same character:

    f_r = ρ_d + ρ_s · D(h) / (4 (cos θ_i + cos θ_o − cos θ_i cos θ_o))
    D(h) = (1 + 4 exp(−cot²θ_h / σ²) / sin⁴θ_h) / (π (1 + 4σ²))

(Ashikhmin & Premože 2007, "Distribution-based BRDFs": an inverted Gaussian
of fibre slopes, D peaks at grazing half-vectors; the denominator is their
smooth replacement of the masking term, reciprocal by construction).

At h = n, sin θ_h = 0 and the Gaussian term is exp(−∞) = 0: sin²θ_h is
floored at 1e-12 so the quotient stays 0, never 0/0.  The denominator is
floored at 1e-6 (both directions at the horizon).

YAML::

    samples: {kind: SampleModel, params: {model: velvet, params: {sigma: 0.35}}}
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.brdf import BRDFModel, ModelParameter, above_horizon


class VelvetModel(BRDFModel):
    name = "velvet"
    parameters = (
        ModelParameter("rho_d", 3, (0.0, 10.0), (0.02, 0.25), 0.05, unit="sr^-1", doc="diffuse term"),
        ModelParameter("rho_s", 3, (0.0, 10.0), (0.1, 1.0), 0.5, unit="1", doc="sheen colour and strength"),
        ModelParameter("sigma", 1, (0.05, 2.0), (0.2, 0.6), 0.35, unit="1", doc="fibre slope spread"),
    )

    def _sheen(self, params, wi, wo):
        up = above_horizon(wi, wo)
        sigma = np.asarray(params["sigma"], float)[:, :1]
        h = wi + wo
        hh = np.maximum(np.einsum("tsk,tsk->ts", h, h), 1e-300)
        cos2 = np.where(up, h[..., 2] ** 2 / hh, 1.0)
        sin2 = np.maximum(1.0 - cos2, 1e-12)
        cot2 = cos2 / sin2
        D = (1.0 + 4.0 * np.exp(-cot2 / (sigma * sigma)) / (sin2 * sin2)) / (np.pi * (1.0 + 4.0 * sigma * sigma))
        ci, co = np.clip(wi[..., 2], 0.0, 1.0), np.clip(wo[..., 2], 0.0, 1.0)
        denom = np.maximum(4.0 * (ci + co - ci * co), 1e-6)
        return np.where(up, D / denom, 0.0), up

    def eval(self, params, wi, wo):
        sheen, up = self._sheen(params, wi, wo)
        f = np.asarray(params["rho_d"], float)[:, None, :] + np.asarray(params["rho_s"], float)[:, None, :] * sheen[..., None]
        return np.where(up[..., None], f, 0.0)

    def glsl(self) -> str:
        """``vec3 brdf_velvet(wi, wo, rho_d, rho_s, sigma)`` in the surface frame."""
        return (
            "vec3 brdf_velvet(vec3 wi, vec3 wo, vec3 rho_d, vec3 rho_s, float sigma) {\n"
            "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
            "    vec3 h = wi + wo;\n"
            "    float cos2 = h.z * h.z / max(dot(h, h), 1e-30);\n"
            "    float sin2 = max(1.0 - cos2, 1e-12);\n"
            "    float D = (1.0 + 4.0 * exp(-(cos2 / sin2) / (sigma * sigma)) / (sin2 * sin2))"
            " / (3.14159265359 * (1.0 + 4.0 * sigma * sigma));\n"
            "    float ci = clamp(wi.z, 0.0, 1.0), co = clamp(wo.z, 0.0, 1.0);\n"
            "    return rho_d + rho_s * (D / max(4.0 * (ci + co - ci * co), 1e-6));\n"
            "}\n"
        )
