"""Measured BRDFs from the public databases: the MERL 100 binary tables and Cornell/ASTM E1392 text files.

Why a package of its own: measured data is how scanned materials are compared
with published ones (MERL, Cornell), and a table is both a model to render
(``merl``: the half-angle table looked up per pixel, on ``cpu`` and ``gl``) and
samples to fit (``MeasuredBRDF``: a 1×1-texel SampledReflectance that ``Fit``
takes, as ALTA fits analytic models to MERL materials).  ``MerlFromModel``
writes a MERL-format file from any installed model, so graphs and tests run on
data they make themselves.  See ``docs/interchange.md``.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from .declarations import MERL


@hookimpl
def sbrdf_brdf_models():
    return [PluginSpec("merl", "sbrdf_measured.model:MerlModel", params=MERL,
                       summary="Tabulated isotropic BRDF from a MERL binary file (90x90x180 half/difference-angle "
                               "table), trilinear or nearest lookup, RGB scale per texel")]


@hookimpl
def sbrdf_node_kinds():
    from .nodes import MeasuredBRDF, MerlFromModel

    return [MeasuredBRDF, MerlFromModel]


@hookimpl
def sbrdf_artifact_kinds():
    from .nodes import MERL_FILE

    return [MERL_FILE]
