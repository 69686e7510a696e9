"""The light-arc capture sources' parameters, declared once and read without importing the sources.

``sbrdf plugins``, graph validation and the reference docs read them through
the :class:`~sbrdf_core.plugin.PluginSpec` of each source (``__init__.py``);
:mod:`.arc`'s classes, imported when a graph captures, take the same tuples
as their ``params``.  This module imports only :mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import Param

LIGHT_ARC = (
    Param("theta_i_deg", "list", [15.0, 25.0, 35.0, 45.0, 55.0, 65.0, 75.0, 85.0],
          "light elevations from the sample normal at its centre, degrees (the paper: ~10 deg steps)", item="float"),
    # The gonio source's own parameters, passed through (its plan is the light arc).
    Param("path", "str", doc="capture folder written pose by pose (as the gonio source), relative to the graph file",
          extra={"path": True}),
    Param("motors", "dict", doc="the gonio source's motors (port: sim for the simulators)"),
    Param("camera", "dict", {"device": "virtual-camera", "params": {}}, "camera device {device, params}"),
    Param("light", "dict", None, "the manifest's light section; default the camera device's", nullable=True),
    Param("geometry", "dict", {}, "rig geometry (RigGeometry fields); the arc needs zero heights and offsets"),
    Param("exposures", "dict", {"times_s": [1.0]}, "exposure brackets, as the gonio source"),
    Param("read", "dict", {}, "parameters of the folder plugin that reads poses back"),
    Param("settle_s", "float", 0.0, "wait after the motors stop", bounds=(0.0, 600.0), unit="s"),
    Param("image_format", "str", "png", "file format of 8/16-bit images", choices=("png", "tif")),
    Param("durable", "bool", True, "fsync every image and journal line"),
)

MESOSTRUCTURE_ARC = (
    Param("texels", "list", [128, 128], "texel grid [U, V] = image size", length=2, item="int", bounds=(1, 16384)),
    Param("size_mm", "list", [20.0, 20.0], "sample size [x, y]", length=2, item="float", bounds=(1e-6, None), unit="mm"),
    Param("mesostructure", "dict", {"height_mm": {"procedural": "bumps", "amplitude_mm": 0.3, "period_mm": 2.0},
                                    "albedo": 0.7},
          "height field and albedo {height_mm, albedo} (sbrdf_lib.mesostructure)"),
    Param("theta_i_deg", "list", [15.0, 25.0, 35.0, 45.0, 55.0, 65.0, 75.0, 85.0], "light elevations from the normal",
          item="float"),
    Param("azimuth_deg", "float", 0.0, "azimuth of the arc's plane from +x", unit="deg"),
    Param("light_distance_mm", "float", 1000.0, "distance of the point light from the sample centre", bounds=(1e-3, None),
          unit="mm"),
    Param("camera_distance_mm", "float", 1000.0, "nominal camera distance (recorded; the view is orthographic)",
          bounds=(1e-3, None), unit="mm"),
    Param("intensity", "float", None, "light intensity I; default light_distance_mm^2 (unit irradiance)", nullable=True),
    Param("shadowing", "bool", False, "compute self-shadowing (a ray march per texel and image)"),
)
