"""materialx: a MaterialX document (``standard_surface``) of the GGX metallic-roughness conversion.

The material is refitted per texel to glTF's metallic-roughness BRDF with
``KHR_materials_specular`` (:func:`sbrdf_lib.convert.to_gltf_pbr`, the
same reading the glTF exporter writes), and mapped onto Autodesk Standard
Surface the way MaterialX's own glTF translation does: ``base`` 1,
``base_color``, ``metalness``, ``specular`` (glTF's specularFactor),
``specular_color`` (glTF's specularColor: Standard Surface tints the
dielectric Fresnel with it, glTF scales F0; they agree at normal incidence),
``specular_roughness`` (both square it into the GGX α), ``specular_IOR``
1.5, ``diffuse_roughness`` 0 (Lambert).  Textures are linear float EXR
(``lin_rec709``) read by ``image`` nodes in one node graph; MaterialX puts
uv (0, 0) at an image's lower-left corner, so rows are written bottom-up.
The document is validated against the MaterialX standard library when it is
written (``attrs["validated"]``).
"""

from __future__ import annotations

import os

import numpy as np

from sbrdf_core.io import write_exr
from sbrdf_core.params import Param

from .common import model_config, texel_grid, write_json
from .ggx import ITERATIONS, STARTS, GGXConverting

#: Standard Surface input <- (map, MaterialX type).
INPUTS = {"base_color": ("base_color", "color3"), "metalness": ("metallic", "float"),
          "specular": ("specular", "float"), "specular_color": ("specular_color", "color3"),
          "specular_roughness": ("roughness", "float")}


def load_stdlib(mx):
    """The MaterialX standard data libraries (node definitions) as a document."""
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


def validate(mx, doc) -> tuple[bool, str]:
    """``doc.validate()`` with the standard library's node definitions in scope."""
    doc.setDataLibrary(load_stdlib(mx))
    return doc.validate()


class MaterialXExporter(GGXConverting):
    """``material.mtlx`` (standard_surface + surfacematerial) with EXR textures of the glTF reading."""

    params = (
        Param("name", "str", "sbrdf", "material name in the document (node names derive from it)"),
        STARTS,
        ITERATIONS,
    )

    def __init__(self, *, name: str = "sbrdf", starts: int = 2, iterations: int = 50):
        self.name = name
        self.starts, self.iterations = starts, iterations

    def convert(self, material):
        return self.gltf_maps(material)

    def write(self, directory, maps, material):
        from sbrdf_core.extras import require

        mx = require("MaterialX", extra="interchange", feature="the materialx exporter")
        d = directory
        files = []
        for m in {m for m, _ in INPUTS.values()}:
            a = np.asarray(maps[m], np.float32)[::-1]  # MaterialX: uv (0, 0) at the image's lower left
            write_exr(os.path.join(d, f"{m}.exr"), np.repeat(a, 3, axis=-1) if a.shape[-1] == 1 else a)
            files.append(f"{m}.exr")
        doc = mx.createDocument()
        ng = doc.addNodeGraph(f"NG_{self.name}")
        shader = doc.addNode("standard_surface", f"SR_{self.name}", "surfaceshader")
        for inp, (m, typ) in INPUTS.items():
            img = ng.addNode("image", f"{m}_image", typ)
            f = img.addInput("file", "filename")
            f.setValueString(f"{m}.exr")
            f.setColorSpace("lin_rec709")
            for axis in ("uaddressmode", "vaddressmode"):
                img.setInputValue(axis, "periodic", "string")
            out = ng.addOutput(f"{m}_out", typ)
            out.setConnectedNode(img)
            i = shader.addInput(inp, typ)
            i.setNodeGraphString(ng.getName())
            i.setOutputString(out.getName())
        shader.setInputValue("base", 1.0, "float")
        shader.setInputValue("specular_IOR", 1.5, "float")
        shader.setInputValue("diffuse_roughness", 0.0, "float")
        doc.addMaterialNode(f"M_{self.name}", shader)
        ok, message = validate(mx, doc)
        if not ok:
            raise ValueError(f"materialx: the document does not validate: {message}")
        mx.writeToXmlFile(doc, os.path.join(d, "material.mtlx"))
        files.append("material.mtlx")
        files.append(write_json(d, "materialx.json", {
            "format": "sbrdf-materialx/1", "model": material.model.name, "model_config": model_config(material),
            **texel_grid(material), "document": "material.mtlx", "material": f"M_{self.name}",
            "shader": "standard_surface", "inputs": {k: f"{m}.exr" for k, (m, _) in INPUTS.items()},
            "rows": "bottom-up (MaterialX uv (0, 0) is the image's lower left)",
            "materialx_version": mx.getVersionString()}))
        return {"files": files, "validated": True, "materialx_version": mx.getVersionString()}
