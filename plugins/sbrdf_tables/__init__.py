"""Measured BSDF tables with transmission (Mühlbacher 2012, seed 004 ch. 3).

The MeasuredTable node kind (table file -> 1x1 SampledReflectance), the
``kurt-transmissive`` BSDF model and the ``grid-search`` fitter.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_node_kinds():
    from .node import MeasuredTableNode

    return [MeasuredTableNode]


@hookimpl
def sbrdf_brdf_models():
    return [PluginSpec("kurt-transmissive", "sbrdf_tables.kurt:KurtTransmissiveModel", params=declarations.KURT,
                       summary="Kurt et al. anisotropic Beckmann lobes, Schlick F, alpha term, + thin-slab "
                               "transmission lobes (Muehlbacher)")]


@hookimpl
def sbrdf_fitters():
    return [PluginSpec("grid-search", "sbrdf_tables.grid_search:GridSearchFitter",
                       params=declarations.GRID_SEARCH,
                       summary="Muehlbacher's hierarchical grid search under the weighted L1 metric (Eq 3.7), "
                               "k_d from a histogram, alternating lobes; optional LM refinement")]
