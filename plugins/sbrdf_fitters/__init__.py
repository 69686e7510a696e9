"""Built-in fitters."""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

LM_PARAMS = (
    Param("model", "str", "lambert", "BRDF model to fit", extra={"plugin_category": "brdf-model"}),
    Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"}),
    Param("iterations", "int", 50, "Levenberg-Marquardt iterations at most", bounds=(1, 10000)),
    Param("tolerance", "float", 1e-10, "stop a texel when its cost improves by less than this fraction", bounds=(0.0, 1.0)),
    Param("damping", "float", 1e-3, "initial Marquardt damping λ", bounds=(0.0, None)),
)


@hookimpl
def sbrdf_fitters():
    return [
        PluginSpec("lm", "sbrdf_fitters.lm:LevenbergMarquardtFitter", LM_PARAMS,
                   summary="Batched Levenberg-Marquardt fit of any BRDF model, vectorised over texels"),
    ]
