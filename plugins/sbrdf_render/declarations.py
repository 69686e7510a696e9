"""The renderers' parameters, declared once and read without importing the renderers.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each renderer (``__init__.py``);
the implementations (:mod:`.preview`, :mod:`.cpu`, :mod:`.gl`), imported when
a graph renders, take the same tuple as their ``params``.  This module imports
only :mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import Param

SCENE = Param("scene", "str", doc="scene file (YAML, docs/scenes.md), relative to the graph file",
              extra={"path": True})
EXPOSURE = Param("exposure", "float", None, "display exposure for the PNG; default: the scene's, else automatic",
                 nullable=True, bounds=(0.0, None))
#: The scene renderers' (``cpu``, ``gl``) shared parameters.
SCENE_RENDERER = (SCENE, EXPOSURE)
CPU = SCENE_RENDERER

PREVIEW = (
    Param("light_pos_mm", "list", [300.0, 0.0, 520.0], "point-light position in the sample frame", length=3,
          item="float", unit="mm"),
    Param("camera_pos_mm", "list", [0.0, 0.0, 800.0], "eye position in the sample frame", length=3, item="float",
          unit="mm"),
    Param("intensity", "float", None, "light radiant intensity I; default |light|² (unit irradiance at the centre)",
          nullable=True, bounds=(0.0, None)),
    Param("exposure", "float", None, "display exposure for the PNG; default maps the 99th percentile to 0.8",
          nullable=True, bounds=(0.0, None)),
)

GL = SCENE_RENDERER + (
    Param("pipeline", "str", "float", "float: one float pass per material; geforce4: McAllister's GeForce 4 path "
          "emulated (8-bit textures, x² and exponent lookup table, x clamped at 1, 2 passes per lobe per light)",
          choices=("float", "geforce4")),
    Param("frames", "int", 1, "frames drawn (their GL-query times are recorded; the last is stored)",
          bounds=(1, 10000)),
)
