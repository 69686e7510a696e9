"""The tables plugin's parameters, declared once and read without importing the model or the fitter.

``sbrdf plugins``, graph validation and the reference docs read them through
the :class:`~sbrdf_core.plugin.PluginSpec` of each contribution
(``__init__.py``); :class:`.kurt.KurtTransmissiveModel` and
:class:`.grid_search.GridSearchFitter`, imported when a graph uses them, take
the same tuples as their ``params``.  This module imports only
:mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import Param

GRID_SEARCH = (
    Param("model", "str", "kurt-transmissive", "BRDF model (the grid search fits kurt-transmissive lobes)",
          choices=("kurt-transmissive",), extra={"plugin_category": "brdf-model"}),
    Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"}),
    Param("n", "int", 9, "values per parameter and level (n^P candidates per level)", bounds=(2, 64)),
    Param("iterations", "int", 4, "grid levels: the first over the search box, each further one ± one step "
          "around the best", bounds=(1, 50)),
    Param("alternations", "int", 2, "passes over the lobes of one hemisphere when there are several",
          bounds=(1, 20)),
    Param("search", "dict", {}, "search box per model parameter, e.g. {m_x_1: [0.01, 0.3]}"),
    Param("fixed", "dict", {}, "model parameters held at a value, e.g. {alpha_1: 0.5, k_d: 0.003}"),
    Param("histogram_bins", "int", 64, "bins of the k_d histogram (linear over [0, 2 x median])",
          bounds=(4, 10000)),
    Param("lm_refine", "bool", False, "refine the grid result by Levenberg-Marquardt (same weights, squared)"),
    Param("lm_iterations", "int", 100, "LM iterations at most", bounds=(1, 10000)),
)

KURT = (
    Param("lobes", "int", 1, "reflection lobes", bounds=(0, 16)),
    Param("transmission_lobes", "int", 0, "transmission lobes (thin slab, ω_t = −ω_i)", bounds=(0, 16)),
)
