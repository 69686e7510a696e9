"""Built-in renderers: ``preview`` (the flat sample), ``cpu`` (the reference) and ``gl`` (real time).

``cpu`` and ``gl`` draw a scene file (:mod:`sbrdf_core.scene`, ``docs/scenes.md``)
and simulate only what it calls for.
"""

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


SCENE = Param("scene", "str", doc="scene file (YAML, docs/scenes.md), relative to the graph file",
              extra={"path": True})
EXPOSURE = Param("exposure", "float", None, "display exposure for the PNG; default: the scene's, else automatic",
                 nullable=True, bounds=(0.0, None))

CPU_PARAMS = (SCENE, EXPOSURE)
GL_PARAMS = (
    SCENE, EXPOSURE,
    Param("pipeline", "str", "float", "float: one float pass per material; geforce4: McAllister's GeForce 4 path "
          "emulated (8-bit textures, x² and exponent lookup table, x clamped at 1, 2 passes per lobe per light)",
          choices=("float", "geforce4")),
    Param("frames", "int", 1, "frames drawn (their GL-query times are recorded; the last is stored)", bounds=(1, 10000)),
)


@hookimpl
def sbrdf_renderers():
    return [
        PluginSpec("preview", "sbrdf_render.preview:PreviewRenderer", PREVIEW_PARAMS,
                   summary="The flat sample under one point light, one pixel per texel (CPU, any model)"),
        PluginSpec("cpu", "sbrdf_render.cpu:CPURenderer", CPU_PARAMS,
                   summary="NumPy reference: ray-cast scene, any BRDF model, exact shadows"),
        PluginSpec("gl", "sbrdf_render.gl:GLRenderer", GL_PARAMS,
                   summary="moderngl/EGL real-time renderer, shaders generated from the scene and the models' GLSL"),
    ]
