"""usd: a USD stage with a UsdShade material (UsdPreviewSurface) bound to a plane of the sample's size.

The material is refitted per texel to the GGX cook-torrance model
(:func:`sbrdf_lib.convert.to_ggx` with ``grazing=False``: ρ_d, F0, α) and
written in UsdPreviewSurface's *specular workflow*, which carries exactly
those three.  Its Fresnel always rises to white at grazing (F90 is 1; there
is no specular weight), so a measured lobe that does not brighten toward
grazing converts with a larger error than in glTF, MaterialX or Mitsuba
(``flagged.png``, ``attrs["flagged"]``):
``diffuseColor`` = π ρ_d (the Lambert albedo), ``specularColor`` = F0 (the
Fresnel reflectance at normal incidence, Schlick), ``roughness`` = √α (the
preview surface squares it into the GGX α), ``useSpecularWorkflow`` 1.
Each is a ``UsdUVTexture`` reading a PNG (colours 8-bit sRGB, roughness
16-bit raw) through a ``UsdPrimvarReader_float2`` of ``st``; USD puts st
(0, 0) at an image's lower-left corner, so rows are written bottom-up.
Values beyond [0, 1] are clipped (``attrs["clipped"]`` counts them).
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

from sbrdf_core.params import Param

from .common import model_config, texel_grid, write_json, write_png
from .declarations import FLAG_ERROR, ITERATIONS, MAX_THETA, STARTS
from .ggx import GGXConverting, write_error_files

#: UsdPreviewSurface input <- (texture file, type, colour space, channels).
TEXTURES = {"diffuseColor": ("diffuse_color.png", "color3f", "sRGB", "rgb"),
            "specularColor": ("specular_color.png", "color3f", "sRGB", "rgb"),
            "roughness": ("roughness.png", "float", "raw", "r")}


class USDExporter(GGXConverting):
    """``material.usda`` with PNG textures of the GGX fit in UsdPreviewSurface's specular workflow."""

    #: Optional modules ``write`` imports: ``sbrdf validate`` reports a missing one with its extra.
    requires = ("pxr",)

    params = (
        Param("name", "str", "Material", "the material prim's name"),
        STARTS,
        ITERATIONS,
        FLAG_ERROR,
        MAX_THETA,
    )

    def __init__(self, *, name: str = "Material", starts: int = 1, iterations: int = 8, flag_error: float = 0.25,
                 max_theta_deg: float = 70.0):
        self.name = name
        self.starts, self.iterations, self.flag_error = starts, iterations, flag_error
        self.max_theta_deg = max_theta_deg

    def convert(self, material):
        return self.ggx_maps(material, grazing=False)

    def textures(self, maps) -> dict[str, np.ndarray]:
        rho_d = np.asarray(maps["rho_d"], np.float64)
        return {"diffuseColor": np.pi * rho_d, "specularColor": np.asarray(maps["f0"], np.float64),
                "roughness": np.sqrt(np.clip(np.asarray(maps["alpha"], np.float64), 0.0, None))}

    def write(self, directory, maps, material):
        from sbrdf_core.extras import require

        require("pxr", extra="interchange", feature="the usd exporter (usd-core)")
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

        d = directory
        files, flag_attrs = write_error_files(d, maps, self.flag_error, rows_bottom_up=True)
        clipped = {}
        for inp, a in self.textures(maps).items():
            file, _, space, _ = TEXTURES[inp]
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
        for inp, (file, typ, space, channels) in TEXTURES.items():
            tex = UsdShade.Shader.Define(stage, f"{mpath}/{inp}Texture")
            tex.CreateIdAttr("UsdUVTexture")
            tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./{file}")
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(space)
            tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
            tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
            tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader_out)
            out = tex.CreateOutput(channels, Sdf.ValueTypeNames.Float3 if channels == "rgb" else Sdf.ValueTypeNames.Float)
            value_type = Sdf.ValueTypeNames.Color3f if typ == "color3f" else Sdf.ValueTypeNames.Float
            surf.CreateInput(inp, value_type).ConnectToSource(out)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
        stage.GetRootLayer().Save()
        files.append("material.usda")
        files.append(write_json(d, "usd.json", {
            "format": "sbrdf-usd/1", "model": material.model.name, "model_config": model_config(material),
            **texel_grid(material), "stage": "material.usda", "material": mpath, "mesh": "/Sample/Plane",
            "workflow": "specular", "inputs": {k: v[0] for k, v in TEXTURES.items()},
            "values": {"diffuseColor": "pi rho_d", "specularColor": "F0", "roughness": "sqrt(alpha)"},
            "rows": "bottom-up (USD st (0, 0) is the image's lower left)", "clipped": clipped,
            "conversion": flag_attrs}))
        return {"files": files, "material_path": mpath, "clipped": clipped, **flag_attrs}
