"""Built-in fitters (generic batched LM, McAllister's procedure, his line search), the SampleModel node and the
Select node (the model with the lowest held-out error).

Each fitter's parameters are declared in :mod:`.declarations`, which imports no fitter; the shared solver is
:mod:`sbrdf_lib.lm`.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_node_kinds():
    from .sample_model import SampleModel
    from .select import Select

    return [SampleModel, Select]


@hookimpl
def sbrdf_fitters():
    return [
        PluginSpec("lm", "sbrdf_fitters.lm:LevenbergMarquardtFitter", params=declarations.LM,
                   summary="Batched Levenberg-Marquardt fit of any BRDF model, vectorised over texels"),
        PluginSpec("mcallister", "sbrdf_fitters.mcallister:McAllisterFitter", params=declarations.MCALLISTER,
                   summary="McAllister's procedure: percentile rho_d, lobes fitted to luminance, rho_s by Eq 4.10"),
        PluginSpec("line-search", "sbrdf_fitters.mcallister:LineSearchFitter", params=declarations.LINE_SEARCH,
                   summary="McAllister's fast single-lobe fit: Brent search over n, least squares for C"),
    ]
