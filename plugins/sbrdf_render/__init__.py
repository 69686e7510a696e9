"""Built-in renderers."""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

PREVIEW_PARAMS = (
    Param("light_pos_mm", "list", [300.0, 0.0, 520.0], "point-light position in the sample frame", length=3, item="float", unit="mm"),
    Param("camera_pos_mm", "list", [0.0, 0.0, 800.0], "eye position in the sample frame", length=3, item="float", unit="mm"),
    Param("intensity", "float", None, "light radiant intensity I; default |light|² (unit irradiance at the centre)",
          nullable=True, bounds=(0.0, None)),
    Param("exposure", "float", None, "display exposure for the PNG; default maps the 99th percentile to 0.8", nullable=True,
          bounds=(0.0, None)),
)


@hookimpl
def sbrdf_renderers():
    return [
        PluginSpec("preview", "sbrdf_render.preview:PreviewRenderer", PREVIEW_PARAMS,
                   summary="The flat sample under one point light, one pixel per texel (CPU, any model)"),
    ]
