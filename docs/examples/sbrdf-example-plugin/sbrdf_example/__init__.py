"""Manifest of the example plugin: what it contributes, nothing imported eagerly."""

from sbrdf_core.plugin import PluginSpec, hookimpl

__version__ = "0.1.0"


@hookimpl
def sbrdf_brdf_models():
    return [
        PluginSpec("minnaert", "sbrdf_example.minnaert:MinnaertModel",
                   summary="Minnaert's limb-darkening diffuse model, f_r = rho_d (cos θi cos θo)^(k-1)"),
    ]
