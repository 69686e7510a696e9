"""lambert: the ideal diffuse reflector.

f_r(ω_i, ω_o) = ρ_d for both directions above the horizon, 0 otherwise.
Energy conservation requires ρ_d ≤ 1/π; measured data may exceed it (a fit
reports what it finds), so the fitting bound is generous.  ρ_d is in sr⁻¹ as
in seed 000 (§4.3), not a unitless albedo.

YAML::

    fit: {kind: Fit, plugin: lm, in: {samples: reflectance}, params: {model: lambert}}
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.brdf import BRDFModel, ModelParameter, above_horizon
from sbrdf_core.plugin import PluginSpec, hookimpl


class LambertModel(BRDFModel):
    name = "lambert"
    anisotropic = False
    suggested_starts = 1  # linear in ρ_d: one minimum
    parameters = (
        ModelParameter("rho_d", channels=3, bounds=(0.0, 10.0), typical=(0.02, 0.3), default=0.1, unit="sr^-1",
                       doc="diffuse reflectance per channel", magnitude=True),
    )

    def eval(self, params, wi, wo):
        rho_d = np.asarray(params["rho_d"])[:, None, :]
        return np.where(above_horizon(wi, wo)[..., None], rho_d, 0.0) * np.ones(wi.shape[:2] + (1,))

    def jacobian(self, params, wi, wo):
        up = above_horizon(wi, wo).astype(float)
        J = np.zeros(wi.shape[:2] + (3, 3))
        for c in range(3):
            J[..., c, c] = up
        return J

    def albedo_bound(self, params):
        """π ρ_d: exact."""
        return (np.pi * np.asarray(params["rho_d"])).max(axis=1)

    def initial_guess(self, f_r, valid, wi, wo):
        w = valid[..., None].astype(float)
        n = np.maximum(w.sum(axis=1), 1)
        return {"rho_d": np.clip((f_r * w).sum(axis=1) / n, 0, 10)}

    def glsl(self):
        return "vec3 brdf_lambert(vec3 wi, vec3 wo, vec3 rho_d) { return (wi.z > 0.0 && wo.z > 0.0) ? rho_d : vec3(0.0); }"


@hookimpl
def sbrdf_brdf_models():
    return [PluginSpec("lambert", "sbrdf_models.lambert:LambertModel",
                       summary="Lambertian diffuse reflector, f_r = rho_d")]
