"""Built-in registration methods."""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl


@hookimpl
def sbrdf_registrations():
    return [
        PluginSpec(
            "texel-aligned",
            "sbrdf_register.texel_aligned:TexelAligned",
            (Param("max_rms_mm", "float", 0.5, "reject poses whose registration residual exceeds this", bounds=(0.0, None), unit="mm"),),
            summary="Images already on the texel grid (simulators): nominal geometry, no resampling",
        ),
    ]
