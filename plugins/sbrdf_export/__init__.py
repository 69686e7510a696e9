"""Exporters: a fitted material for the tools people hand materials to.

Why a package of its own: each exporter writes another tool's format (glTF
2.0, an EXR texture set with a JSON sidecar, a MaterialX document, a USD
material, a Mitsuba 3 scene), and all but the EXR set need the GGX
metallic-roughness conversion of :mod:`sbrdf_lib.convert`.  glTF's writer and
reader are hand-written (:mod:`.gltf`, no third-party dependency: PNGs go
through ``sbrdf_core.io``; :mod:`.threejs` renders an export in three.js for
the round trips); the others need heavy optional libraries (the
``[interchange]`` extra), imported only when an exporter writes.  Each
exporter is the ``plugin:`` of an ``Export`` node (docs/interchange.md).
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_exporters():
    return [
        PluginSpec("gltf", "sbrdf_export.gltf:GLTFExporter", params=declarations.GLTF,
                   summary="glTF 2.0 (.gltf + .bin + PNGs, or .glb): a textured quad with metallic-roughness PBR "
                           "(+ KHR_materials_specular) from a per-texel GGX conversion fit, error per texel"),
        PluginSpec("exr-set", "sbrdf_export.exr_set:EXRSetExporter", params=declarations.EXR_SET,
                   summary="One float EXR per model parameter plus a JSON sidecar (units, channels, model, texel "
                           "grid, GLSL): the model's own maps, no conversion"),
        PluginSpec("materialx", "sbrdf_export.materialx:MaterialXExporter", params=declarations.MATERIALX,
                   summary="MaterialX document (standard_surface with image nodes) of the GGX metallic-roughness "
                           "conversion"),
        PluginSpec("usd", "sbrdf_export.usd:USDExporter", params=declarations.USD,
                   summary="USD stage with a UsdShade material (UsdPreviewSurface + UsdUVTexture) bound to a plane, "
                           "from the GGX metallic-roughness conversion"),
        PluginSpec("mitsuba", "sbrdf_export.mitsuba:MitsubaExporter", params=declarations.MITSUBA,
                   summary="Mitsuba 3 scene (XML + EXR bitmaps): diffuse + GGX rough conductor from the GGX "
                           "conversion, camera and lights from a project scene file"),
    ]
