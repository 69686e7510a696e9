"""Built-in BRDF models.  Each model is one module named as registered."""

from sbrdf_core.plugin import PluginSpec, hookimpl


@hookimpl
def sbrdf_brdf_models():
    return [
        PluginSpec("lambert", "sbrdf_models.lambert:LambertModel", summary="Lambertian diffuse reflector, f_r = rho_d"),
    ]
