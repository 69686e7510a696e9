"""glTF 2.0 export: a fitted material as a textured quad that three.js, Blender, Unreal and every glTF viewer load.

Why a package of its own: glTF carries one fixed BRDF (metallic-roughness
GGX, extended by ``KHR_materials_specular``), so the export is a conversion
fit (:mod:`sbrdf_lib.convert`) with its error per texel, plus a hand-written
glTF/GLB writer and reader (no third-party dependency: PNGs go through
``sbrdf_core.io``).  The exporter is the ``plugin:`` of an ``Export`` node
(docs/interchange.md, section "glTF 2.0").
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from .declarations import GLTF


@hookimpl
def sbrdf_exporters():
    return [
        PluginSpec("gltf", "sbrdf_gltf.exporter:GLTFExporter", params=GLTF,
                   summary="glTF 2.0 (.gltf + .bin + PNGs, or .glb): a textured quad with metallic-roughness PBR "
                           "(+ KHR_materials_specular) from a per-texel GGX conversion fit, error per texel"),
    ]
