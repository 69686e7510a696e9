"""minnaert: Minnaert's darkening law, a one-parameter generalised Lambertian.

=========  ========  =====  ==================================================
parameter  channels  unit   meaning
=========  ========  =====  ==================================================
rho_d      3         sr^-1  diffuse value at normal incidence and view
k          1                darkening exponent; k = 1 is Lambertian,
                            k < 1 brightens toward grazing (velvet, dust)
=========  ========  =====  ==================================================

f_r = ρ_d · (cos θ_i cos θ_o)^(k − 1) (Minnaert 1941).  Reciprocal by
construction.  For k < 1 the value grows without bound at grazing angles, so
``eval`` clamps the cosines at 1e-3 to stay finite.

``fit_kernel`` is the same mathematics compiled for the fitting engine: f_r
and its Jacobian at one direction pair.  The model is its own fit form, so
the kernel's x is the packed (ρ_d, k).
"""

from __future__ import annotations

import math

import numpy as np

from sbrdf_core.brdf import BRDFModel, ModelParameter, above_horizon

MIN_COS = 1e-3


def fit_kernel(x, cfg, wi, wo, f, J):
    """f_r = ρ_d (cos θ_i cos θ_o)^(k − 1) and ∂f_r/∂(ρ_d, k) at one direction pair; zeros below the horizon."""
    for ch in range(3):
        f[ch] = 0.0
        for j in range(4):
            J[ch, j] = 0.0
    if not (wi[2] > 0.0 and wo[2] > 0.0):  # not ≤ 0: NaN directions give 0, as eval's horizon mask does
        return
    c = min(max(wi[2], MIN_COS), 1.0) * min(max(wo[2], MIN_COS), 1.0)
    g = c ** (x[3] - 1.0)
    dg = g * math.log(c)  # ∂g/∂k
    for ch in range(3):
        f[ch] = g * x[ch]
        J[ch, ch] = g
        J[ch, 3] = dg * x[ch]


class MinnaertModel(BRDFModel):
    name = "minnaert"
    anisotropic = False
    fit_kernel = staticmethod(fit_kernel)
    parameters = (
        ModelParameter("rho_d", channels=3, bounds=(0.0, 10.0), typical=(0.05, 0.3), default=0.1, unit="sr^-1"),
        ModelParameter("k", channels=1, bounds=(0.2, 3.0), typical=(0.6, 1.4), default=1.0),
    )

    def _base(self, wi, wo):
        c = np.clip(wi[..., 2], MIN_COS, 1) * np.clip(wo[..., 2], MIN_COS, 1)
        return c, above_horizon(wi, wo)

    def eval(self, params, wi, wo):
        c, up = self._base(wi, wo)
        k = params["k"][:, :1]  # (T, 1)
        return np.where(up, c ** (k - 1), 0.0)[..., None] * params["rho_d"][:, None, :]

    def jacobian(self, params, wi, wo):
        c, up = self._base(wi, wo)
        k = params["k"][:, :1]
        g = np.where(up, c ** (k - 1), 0.0)  # (T, S)
        J = np.zeros(wi.shape[:2] + (3, 4))
        for ch in range(3):
            J[..., ch, ch] = g  # ∂f_c/∂ρ_d,c
        J[..., 3] = (g * np.log(c))[..., None] * params["rho_d"][:, None, :]  # ∂f/∂k
        return J

    def glsl(self):
        return (
            "vec3 brdf_minnaert(vec3 wi, vec3 wo, vec3 rho_d, float k) {\n"
            "  if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
            "  return rho_d * pow(max(wi.z, 1e-3) * max(wo.z, 1e-3), k - 1.0);\n}"
        )
