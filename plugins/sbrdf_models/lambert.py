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
from sbrdf_core.constraints_glsl import clip_lines


def fit_kernel(x, cfg, wi, wo, f, J):
    """f_r = ρ_d and its Jacobian, the identity, at one direction pair (the fit form is the model: x = ρ_d);
    zeros below the horizon, as :meth:`LambertModel.eval`."""
    up = wi[2] > 0.0 and wo[2] > 0.0  # written so, not as ≤ 0, that NaN directions give 0 as above_horizon does
    for c in range(3):
        f[c] = x[c] if up else 0.0
        for k in range(3):
            J[c, k] = 1.0 if up and k == c else 0.0


class LambertModel(BRDFModel):
    name = "lambert"
    anisotropic = False
    suggested_starts = 1  # linear in ρ_d: one minimum
    reads_peak_cosine = False
    fit_kernel = staticmethod(fit_kernel)
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

    def glsl_fit_constrain(self) -> str:
        """``brdf_fit_constrain``: the bounds and ρ_d ≤ peak (the default :meth:`constrain`), for ``lm-gl``."""
        return "\n".join(["void brdf_fit_constrain(inout float x[3], float peak, float resolution, float peak_cosine, "
                          "float growth, float max_theta) {"] + clip_lines(self.fit_form()) + ["}", ""])
