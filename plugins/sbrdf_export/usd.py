"""usd: a USD stage with a UsdShade material (UsdPreviewSurface) bound to a plane of the sample's size.

The material is fitted per texel to UsdPreviewSurface's own BRDF as Storm
shades it (:mod:`sbrdf_lib.usd_preview`: the specular workflow's lobe, whose
Fresnel always rises to white at grazing, plus the clearcoat lobe, whose
Fresnel runs from c·R to c), cosine-weighted over the directions a viewer
meets, so ``error`` is the error of what a USD renderer shows.  The gloss of a
measured lobe that does not brighten toward grazing goes into the clearcoat
(``clearcoat`` weight, ``ior`` for its normal-incidence Fresnel R,
``clearcoatRoughness``), the first lobe stays the rough grazing term every
UsdPreviewSurface has; ``clearcoat: false`` fits the first lobe alone.
Texels whose error is above ``flag_error`` are flagged (``flagged.png``,
``attrs["flagged"]``).

Inputs (``useSpecularWorkflow`` 1): ``diffuseColor`` = d, ``specularColor`` =
F0, ``roughness`` (USD squares it into the GGX α), and with the clearcoat
``clearcoat``, ``clearcoatRoughness`` and ``ior`` = (1 + √R)/(1 − √R) (in
the specular workflow ior sets the clearcoat's Fresnel only).  Each is a
``UsdUVTexture`` reading a PNG (colours 8-bit sRGB, the rest 16-bit raw; the
ior texture holds (ior − 1)/(:data:`IOR_MAX` − 1), undone by the texture's
``scale`` and ``bias``) through a ``UsdPrimvarReader_float2`` of ``st``; USD
puts st (0, 0) at an image's lower-left corner, so rows are written bottom-up.
The primvar reader's ``varname`` and the material's ``frame:stPrimvarName``
are ``string`` inputs, as UsdPreviewSurface's shader definitions declare
(``usdchecker`` / ``UsdValidation`` report a ``token`` there).

The stage (``material.usda``, Z up, millimetres) holds ``/Sample``, a
quad of the sample's size with ``st`` spanning [0, 1]², and
``/Sample/Looks/Material`` bound to it, so it opens in usdview, Blender or
Omniverse as it is and the material can be referenced into other stages.
"""

from __future__ import annotations

import os

import numpy as np

from .common import model_config, texel_grid, write_json, write_png
from .declarations import USD
from .ggx import GGXConverting, with_flags, write_error_files

#: UsdPreviewSurface input <- (texture file, type, colour space, channels).
TEXTURES = {"diffuseColor": ("diffuse_color.png", "color3f", "sRGB", "rgb"),
            "specularColor": ("specular_color.png", "color3f", "sRGB", "rgb"),
            "roughness": ("roughness.png", "float", "raw", "r")}
#: The clearcoat's inputs, written with ``clearcoat`` on.
CLEARCOAT_TEXTURES = {"clearcoat": ("clearcoat.png", "float", "raw", "r"),
                      "clearcoatRoughness": ("clearcoat_roughness.png", "float", "raw", "r"),
                      "ior": ("ior.png", "float", "raw", "r")}
#: The ior texture's range: [1, IOR_MAX] stored as [0, 1] (the clearcoat's largest R, 0.81, is ior 19).
IOR_MAX = 19.0


class USDExporter(GGXConverting):
    """``material.usda`` with PNG textures of the UsdPreviewSurface fit (specular workflow and clearcoat)."""

    #: Optional modules ``write`` imports: ``sbrdf validate`` reports a missing one with its extra.
    requires = ("pxr",)

    params = USD

    def __init__(self, *, name: str = "Material", clearcoat: bool = True, starts: int = 1, iterations: int = 8,
                 flag_error: float = 0.25, max_theta_deg: float = 70.0):
        self.name = name
        self.clearcoat = clearcoat
        self.starts, self.iterations, self.flag_error = starts, iterations, flag_error
        self.max_theta_deg = max_theta_deg

    def convert(self, material):
        from sbrdf_lib.usd_preview import to_preview_surface_blocks

        return with_flags(to_preview_surface_blocks(material.model, material.params, self._ggx(),
                                                    clearcoat=self.clearcoat, starts=self.starts,
                                                    iterations=self.iterations, max_theta_deg=self.max_theta_deg),
                          self.flag_error)

    def textures(self, maps) -> dict[str, np.ndarray]:
        """The stored maps as the textures' values (the ior texture as (ior − 1)/(IOR_MAX − 1))."""
        from sbrdf_lib.usd_preview import ior_of

        get = lambda k: np.asarray(maps[k], np.float64)  # noqa: E731
        out = {"diffuseColor": get("diffuse_color"), "specularColor": get("specular_color"),
               "roughness": get("roughness")}
        if self.clearcoat:
            out.update(clearcoat=get("clearcoat"), clearcoatRoughness=get("clearcoat_roughness"),
                       ior=(ior_of(get("clearcoat_f0")) - 1.0) / (IOR_MAX - 1.0))
        return out

    def write(self, directory, maps, material):
        from sbrdf_core.extras import require

        require("pxr", extra="interchange", feature="the usd exporter (usd-core)")
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

        d = directory
        files, flag_attrs = write_error_files(d, maps, self.flag_error, rows_bottom_up=True)
        clipped = {}
        inputs = {**TEXTURES, **(CLEARCOAT_TEXTURES if self.clearcoat else {})}
        for inp, a in self.textures(maps).items():
            file, _, space, _ = inputs[inp]
            clipped[inp] = int(np.count_nonzero((a < 0) | (a > 1)))
            write_png(os.path.join(d, file), a[::-1], srgb=space == "sRGB")  # st (0, 0) at the lower left
            files.append(file)
        path = os.path.join(d, "material.usda")
        stage = Usd.Stage.CreateNew(path)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 0.001)
        root = UsdGeom.Xform.Define(stage, "/Sample")
        stage.SetDefaultPrim(root.GetPrim())
        w, h = (float(x) for x in material.size_mm)
        mesh = UsdGeom.Mesh.Define(stage, "/Sample/Plane")
        mesh.CreatePointsAttr([Gf.Vec3f(-w / 2, -h / 2, 0), Gf.Vec3f(w / 2, -h / 2, 0), Gf.Vec3f(w / 2, h / 2, 0),
                               Gf.Vec3f(-w / 2, h / 2, 0)])
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        mesh.CreateNormalsAttr([Gf.Vec3f(0, 0, 1)] * 4)
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        mesh.CreateExtentAttr([Gf.Vec3f(-w / 2, -h / 2, 0), Gf.Vec3f(w / 2, h / 2, 0)])
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                       UsdGeom.Tokens.vertex)
        st.Set([Gf.Vec2f(0, 0), Gf.Vec2f(1, 0), Gf.Vec2f(1, 1), Gf.Vec2f(0, 1)])
        mpath = f"/Sample/Looks/{self.name}"
        UsdGeom.Scope.Define(stage, "/Sample/Looks")
        mat = UsdShade.Material.Define(stage, mpath)
        surf = UsdShade.Shader.Define(stage, f"{mpath}/PreviewSurface")
        surf.CreateIdAttr("UsdPreviewSurface")
        surf.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
        surf.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(1.0)
        mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
        reader = UsdShade.Shader.Define(stage, f"{mpath}/stReader")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        varname = mat.CreateInput("frame:stPrimvarName", Sdf.ValueTypeNames.String)
        varname.Set("st")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).ConnectToSource(varname)
        reader_out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        for inp, (file, typ, space, channels) in inputs.items():
            tex = UsdShade.Shader.Define(stage, f"{mpath}/{inp}Texture")
            tex.CreateIdAttr("UsdUVTexture")
            tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./{file}")
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(space)
            tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
            tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
            tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader_out)
            if inp == "ior":  # the texture holds (ior − 1)/(IOR_MAX − 1)
                tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(IOR_MAX - 1.0, 1.0, 1.0, 1.0))
                tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(1.0, 0.0, 0.0, 0.0))
            out = tex.CreateOutput(channels, Sdf.ValueTypeNames.Float3 if channels == "rgb" else Sdf.ValueTypeNames.Float)
            value_type = Sdf.ValueTypeNames.Color3f if typ == "color3f" else Sdf.ValueTypeNames.Float
            surf.CreateInput(inp, value_type).ConnectToSource(out)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
        stage.GetRootLayer().Save()
        files.append("material.usda")
        files.append(write_json(d, "usd.json", {
            "format": "sbrdf-usd/1", "model": material.model.name, "model_config": model_config(material),
            **texel_grid(material), "stage": "material.usda", "material": mpath, "mesh": "/Sample/Plane",
            "workflow": "specular", "clearcoat": self.clearcoat, "inputs": {k: v[0] for k, v in inputs.items()},
            "values": {"diffuseColor": "d", "specularColor": "F0", "roughness": "sqrt(alpha)",
                       **({"clearcoat": "c", "clearcoatRoughness": "sqrt(alpha_c)",
                           "ior": f"1 + {IOR_MAX - 1.0:g} texture (R = ((1 - ior)/(1 + ior))^2)"}
                          if self.clearcoat else {})},
            "rows": "bottom-up (USD st (0, 0) is the image's lower left)", "clipped": clipped,
            "conversion": flag_attrs}))
        return {"files": files, "material_path": mpath, "clipped": clipped, **flag_attrs}
