"""Measured BSDF tables with transmission (Mühlbacher 2012, seed 004 ch. 3).

The MeasuredTable node kind (table file -> 1x1 SampledReflectance), the
``kurt-transmissive`` BSDF model and the ``grid-search`` fitter.
"""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

from .kurt import PARAMS as KURT_PARAMS

GRID_SEARCH_PARAMS = (
    Param("model", "str", "kurt-transmissive", "BRDF model (the grid search fits kurt-transmissive lobes)",
          choices=["kurt-transmissive"], extra={"plugin_category": "brdf-model"}),
    Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"}),
    Param("n", "int", 9, "values per parameter and level (n^P candidates per level)", bounds=(2, 64)),
    Param("iterations", "int", 4, "grid levels: the first over the search box, each further one ± one step "
          "around the best", bounds=(1, 50)),
    Param("alternations", "int", 2, "passes over the lobes of one hemisphere when there are several", bounds=(1, 20)),
    Param("search", "dict", {}, "search box per model parameter, e.g. {m_x_1: [0.01, 0.3]}"),
    Param("fixed", "dict", {}, "model parameters held at a value, e.g. {alpha_1: 0.5, k_d: 0.003}"),
    Param("histogram_bins", "int", 64, "bins of the k_d histogram (linear over [0, 2 x median])", bounds=(4, 10000)),
    Param("lm_refine", "bool", False, "refine the grid result by Levenberg-Marquardt (same weights, squared)"),
    Param("lm_iterations", "int", 100, "LM iterations at most", bounds=(1, 10000)),
)


@hookimpl
def sbrdf_node_kinds():
    from .node import MeasuredTableNode

    return [MeasuredTableNode]


@hookimpl
def sbrdf_brdf_models():
    return [PluginSpec("kurt-transmissive", "sbrdf_tables.kurt:KurtTransmissiveModel", KURT_PARAMS,
                       summary="Kurt et al. anisotropic Beckmann lobes, Schlick F, alpha term, + thin-slab "
                               "transmission lobes (Muehlbacher)")]


@hookimpl
def sbrdf_fitters():
    return [PluginSpec("grid-search", "sbrdf_tables.grid_search:GridSearchFitter", GRID_SEARCH_PARAMS,
                       summary="Muehlbacher's hierarchical grid search under the weighted L1 metric (Eq 3.7), "
                               "k_d from a histogram, alternating lobes; optional LM refinement")]
