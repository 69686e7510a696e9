"""The parameter declarations the fitters built on :mod:`sbrdf_lib.lm` share.

Fitters declare their parameters in modules that listing and validation read
without importing the solver (``sbrdf plugins`` imports no NumPy kernel for
them); this module imports only :mod:`sbrdf_core.params`, and
:mod:`sbrdf_lib.lm` reads the same names.
"""

from __future__ import annotations

from sbrdf_core.params import Param

__all__ = ["WEIGHTING", "WEIGHTINGS"]

#: What the least squares weighs, as the power p of each residual's weight 1 / (|f_r| + floor)^p
#: (:func:`sbrdf_lib.lm.sample_weights`): residuals in sr⁻¹, for shot noise (σ ∝ √f_r), or relative to the value.
WEIGHTINGS = {"absolute": 0.0, "shot-noise": 0.5, "relative": 1.0}
#: The ``weighting`` parameter of the fitters that minimise :func:`sbrdf_lib.lm.fit_model`'s objective
#: (``lm``, ``lm-gl``).
WEIGHTING = Param("weighting", "str", "shot-noise", "what the least squares weighs: absolute = residuals in sr^-1, "
                  "ruled by a lobe's peak samples; shot-noise = divided by sqrt(f_r + a floor), the "
                  "maximum-likelihood weighting of photographed values; relative = divided by f_r + a floor, the "
                  "shape in ratio (floor: half the texel's median sample; docs/fitting.md)",
                  choices=tuple(WEIGHTINGS))
