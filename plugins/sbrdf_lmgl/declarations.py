"""The ``lm-gl`` fitter's parameters, declared once and read without importing the fitter.

``sbrdf plugins``, graph validation and the reference docs read them through
the fitter's :class:`~sbrdf_core.plugin.PluginSpec` (``__init__.py``);
:class:`.fitter.GLLevenbergMarquardtFitter`, imported when a graph fits,
takes the same tuple as its ``params``.  This module imports only
:mod:`sbrdf_core.params` and :mod:`sbrdf_lib.lm_params`.
"""

from __future__ import annotations

from sbrdf_core.params import Param
from sbrdf_lib.lm_params import WEIGHTING

LM_GL = (
    Param("model", "str", "lambert", "BRDF model to fit (it must have a fit_kernel)",
          extra={"plugin_category": "brdf-model"}),
    Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"}),
    Param("iterations", "int", 200, "Levenberg-Marquardt iterations at most, per texel (as lm)", bounds=(1, 10000)),
    Param("tolerance", "float", 1e-4, "stop a texel when its cost improves by less than this fraction",
          bounds=(0.0, 1.0)),
    Param("damping", "float", 1e-3, "initial Marquardt damping λ", bounds=(0.0, None)),
    Param("starts", "int", 0, "LM runs per texel from its best-scoring starting points, as for lm (0 = the "
          "model's suggestion, 1 = its initial guess alone)", bounds=(0, 64)),
    Param("fixed", "list", [], "fit-form parameter names held at their initial value", item="str"),
    Param("seed", "int", 0, "seed of the Sobol starting points"),
    Param("loss", "str", "linear", "linear (least squares), or huber / soft-l1 (iteratively reweighted)",
          choices=["linear", "huber", "soft-l1"]),
    WEIGHTING,
    Param("loss_scale", "float", 0.0, "residual (sr^-1) where a robust loss turns linear; 0 = 1.4826 x the "
          "texel's median absolute residual", bounds=(0.0, None)),
    Param("tile", "int", 4096, "texels per compute dispatch (samples of two tiles are on the GPU at once)",
          bounds=(64, None)),
    Param("cpu_finish", "bool", True, "texels unconverged after `iterations` (ill-conditioned lobes: damping "
          "slows the steps) get another `iterations` on the GPU from where they stopped (linear loss, limits "
          "projected in the shader or none), then the CPU solver in float64 finishes what is left; false: they "
          "are flagged not converged"),
)
