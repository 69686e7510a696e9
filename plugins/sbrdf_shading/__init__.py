"""Decoupled mesostructure: shading maps (Kautz, Sattler, Sarlette, Klein, Seidel 2003; seed 002).

A material is photographed from a fixed orthogonal view under a light moving
along an arc; the images are resampled into a *shading map* whose slices'
average radiance rises linearly (node kind ``ShadingMap``), optionally
compressed per texel to ``k_s · r^K`` (node kind ``CompressShadingMap``), and
rendered with any BRDF model by looking the map up with
``r = σ f_r cos θ_i`` (:mod:`sbrdf_shading.shade` in NumPy,
:mod:`sbrdf_shading.glsl` for the GL renderer).  Capture sources
``light-arc`` (the gonio rig + any camera device) and ``mesostructure-arc``
(a fast texel-aligned simulator).  See ``docs/shading-maps.md``.
"""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations
from .artifacts import KINDS


@hookimpl
def sbrdf_artifact_kinds():
    return list(KINDS)


@hookimpl
def sbrdf_scene_keys():
    """A scene material with ``shading_map:`` and ``model:`` shades by the map (``docs/shading-maps.md``)."""
    return {"material": (
        Param("shading_map", "str", None, "'input' (the Render node's input) or a ShadingMap or PowerShadingMap store "
              "(relative to the scene file), looked up with model: and params: (Kautz et al. 2003, docs/shading-maps.md)",
              nullable=True, extra={"store": True}),
        Param("variant", "str", "r", "shading-map lookup (Fig 6): by r, by outgoing radiance, by angle, or a slice as "
              "texture", choices=("r", "radiance", "angle", "texture")),
        Param("above_max", "str", "clamp", "shading-map lookups above a_max: clamp to, or scale, the brightest slice",
              choices=("clamp", "scale")),
        Param("sigma", "float", 1.0, "σ of Eq 2: the shading-mapped material's shade", bounds=(0.0, None)),
    )}


@hookimpl
def sbrdf_node_kinds():
    from .node import CompressShadingMapNode, ShadingMapNode

    return [ShadingMapNode, CompressShadingMapNode]


@hookimpl
def sbrdf_captures():
    return [
        PluginSpec("light-arc", "sbrdf_shading.arc:LightArcCapture", params=declarations.LIGHT_ARC,
                   summary="The gonio rig with a fixed orthogonal view and the light on an arc (shading maps)"),
        PluginSpec("mesostructure-arc", "sbrdf_shading.arc:MesostructureArcCapture",
                   params=declarations.MESOSTRUCTURE_ARC,
                   summary="Texel-aligned simulated light-arc images of a height field with per-texel albedo"),
    ]
