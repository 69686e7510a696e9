"""The fitters' parameters, declared once and read without importing the fitters.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each fitter (``__init__.py``);
the implementations (:mod:`.lm`, :mod:`.lm_gl`, :mod:`.mcallister`), imported
when a graph fits, take the same tuples as their ``params``.  This module
imports only :mod:`sbrdf_core.params` and :mod:`sbrdf_lib.lm_params` (neither
moderngl nor a solver).
"""

from __future__ import annotations

from sbrdf_core.params import Param
from sbrdf_lib.lm_params import WEIGHTING

MODEL = Param("model", "str", "lambert", "BRDF model to fit", extra={"plugin_category": "brdf-model"})
MODEL_PARAMS = Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"})
ITERATIONS = Param("iterations", "int", 200, "Levenberg-Marquardt iterations at most, per texel (a texel stops when "
                   "it converges: most need under 20; sharp lobes on grazing data take more)", bounds=(1, 10000))
TOLERANCE = Param("tolerance", "float", 1e-4, "stop a texel when its cost improves by less than this fraction",
                  bounds=(0.0, 1.0))

LM = (
    MODEL,
    MODEL_PARAMS,
    ITERATIONS,
    TOLERANCE,
    Param("damping", "float", 1e-3, "initial Marquardt damping λ", bounds=(0.0, None)),
    Param("starts", "int", 0, "LM runs per texel, from its best-scoring starting points (the model's guess and "
          "a Sobol set over typical shapes, magnitudes solved); the texel keeps its best. 0 = the model's "
          "suggestion (2 for Cook-Torrance, Phong, Ward and 3+ Lafortune lobes: 4); 1 = the guess alone",
          bounds=(0, 64)),
    Param("fixed", "list", [], "fit-form parameter names held at their initial value", item="str"),
    Param("seed", "int", 0, "seed of the Sobol starting points"),
    Param("loss", "str", "linear", "linear (least squares), or huber / soft-l1: outliers such as dust spikes "
          "are down-weighted (iteratively reweighted)", choices=("linear", "huber", "soft-l1")),
    Param("loss_scale", "float", 0.0, "residual (sr^-1) where a robust loss turns from quadratic to linear; "
          "0 = 1.4826 x the texel's median absolute residual", bounds=(0.0, None)),
    WEIGHTING,
)

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
          choices=("linear", "huber", "soft-l1")),
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

ROOT_FLOOR = Param("root_floor", "float", 0.01, "line search: drop samples whose luminance residual is below this "
                   "fraction of the texel's peak (0 = as written, which fails at any noise: the n-th root of a "
                   "near-zero noisy residual is near 1)", bounds=(0.0, 1.0))
#: The parameters McAllister's procedure and its line-search variant share.
SHARED = (
    Param("model", "str", "lafortune", "BRDF model (McAllister's procedure fits Lafortune lobes)",
          choices=("lafortune",), extra={"plugin_category": "brdf-model"}),
    MODEL_PARAMS,
    Param("diffuse", "str", "percentile", "rho_d estimate per channel", choices=("percentile", "min", "weighted-mean")),
    Param("percentile", "float", 10.0, "percentile of the samples taken as rho_d", bounds=(0.0, 100.0)),
    Param("colour_space", "str", "mcallister", "luminance weights of the working RGB space",
          choices=("mcallister", "rec709", "rec2020")),
    Param("rho_s_guard", "float", 0.05, "Eq 4.10 uses samples whose luminance residual is at least this fraction "
          "of the texel's largest", bounds=(0.0, 1.0)),
)

MCALLISTER = SHARED + (
    Param("lobe_fit", "str", "lm", "how the lobe shape is fitted to the luminance residual",
          choices=("lm", "line-search")),
    Param("lobe_2_start", "str", "text", "lobe 2 starts from the text's guess C=(1,1,1), n=5, or from the "
          "1-lobe fit", choices=("text", "one-lobe")),
    ITERATIONS,
    TOLERANCE,
    Param("starts", "int", 1, "starting points of the lobe fit: 1 = the procedure's own, more adds Sobol starts "
          "and keeps the best", bounds=(1, 64)),
    Param("objective", "str", "root", "line search residual: in n-th-root space (as written) or BRDF space",
          choices=("root", "brdf")),
    ROOT_FLOOR,
)

LINE_SEARCH = SHARED + (
    Param("objective", "str", "root", "residual in n-th-root space (as written, Eq 4.9) or BRDF space",
          choices=("root", "brdf")),
    ROOT_FLOOR,
)
