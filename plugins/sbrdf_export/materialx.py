"""materialx: a MaterialX document (``standard_surface``) of the GGX metallic-roughness conversion.

The material is refitted per texel to glTF's metallic-roughness BRDF with
``KHR_materials_specular`` (:func:`sbrdf_lib.convert.to_gltf_pbr`, the
same reading the glTF exporter writes), and mapped onto Autodesk Standard
Surface the way MaterialX's own glTF translation does: ``base`` 1,
``base_color``, ``metalness``, ``specular`` (glTF's specularFactor s: the
weight of the whole specular lobe, grazing included), ``specular_IOR`` per
texel (the dielectric whose normal-incidence Fresnel is the largest channel of
F0c = min(0.04 · specularColor, 1)) and ``specular_color`` = F0c / max(F0c)
(Standard Surface tints the dielectric Fresnel with it, so it stays in
[0, 1] as its definition expects, instead of glTF's specularColor, which may
reach 25), ``specular_roughness`` (both square it into the GGX α),
``diffuse_roughness`` 0 (Lambert).  The specular lobe is then s · tint ·
F_dielectric(IOR): s F0c at normal incidence, s at grazing, as in glTF.  Textures are linear float EXR
(``lin_rec709``) read by ``image`` nodes in one node graph; MaterialX puts
uv (0, 0) at an image's lower-left corner, so rows are written bottom-up.
The document is validated against the MaterialX standard library when it is
written (``attrs["validated"]``).
"""

from __future__ import annotations

import os

import numpy as np

from sbrdf_core.io import write_exr

from .common import model_config, texel_grid, write_json
from .declarations import MATERIALX
from .ggx import GGXConverting, write_error_files

#: Standard Surface input <- (map, MaterialX type).
INPUTS = {"base_color": ("base_color", "color3"), "metalness": ("metallic", "float"),
          "specular": ("specular", "float"), "specular_color": ("specular_tint", "color3"),
          "specular_IOR": ("specular_ior", "float"), "specular_roughness": ("roughness", "float")}
#: Largest normal-incidence reflectance written as an IOR (F0 0.96: IOR 49; F0 1 has none).
MAX_F0 = 0.96


def standard_surface_maps(maps: dict) -> dict[str, np.ndarray]:
    """glTF maps -> Standard Surface's: ``specular_tint`` = F0c / max F0c in [0, 1], ``specular_ior`` ≥ 1.

    F0c = min(0.04 · specularColor, 1) (glTF's dielectric F0 before specularFactor); a black F0c has tint 1
    and IOR 1 (no reflection).
    """
    from sbrdf_lib.convert import DIELECTRIC_F0

    f0 = np.clip(DIELECTRIC_F0 * np.asarray(maps["specular_color"], np.float64), 0.0, 1.0)
    top = f0.max(axis=-1, keepdims=True)
    with np.errstate(all="ignore"):
        tint = np.where(top > 0, f0 / top, 1.0)
    r = np.sqrt(np.clip(top, 0.0, MAX_F0))
    out = {k: np.asarray(v, np.float64) for k, v in maps.items()}
    out["specular_tint"] = tint
    out["specular_ior"] = (1.0 + r) / (1.0 - r)
    return out


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

    #: Optional modules ``write`` imports: ``sbrdf validate`` reports a missing one with its extra.
    requires = ("MaterialX",)

    params = MATERIALX

    def __init__(self, *, name: str = "sbrdf", starts: int = 1, iterations: int = 8, flag_error: float = 0.25,
                 max_theta_deg: float = 70.0):
        self.name = name
        self.starts, self.iterations, self.flag_error = starts, iterations, flag_error
        self.max_theta_deg = max_theta_deg

    def convert(self, material):
        return self.gltf_maps(material)

    def write(self, directory, maps, material):
        from sbrdf_core.extras import require

        mx = require("MaterialX", extra="interchange", feature="the materialx exporter")
        d = directory
        files, flag_attrs = write_error_files(d, maps, self.flag_error, rows_bottom_up=True)
        maps = standard_surface_maps(maps)
        for m in sorted({m for m, _ in INPUTS.values()}):
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
            "materialx_version": mx.getVersionString(), "conversion": flag_attrs}))
        return {"files": files, "validated": True, "materialx_version": mx.getVersionString(), **flag_attrs}
