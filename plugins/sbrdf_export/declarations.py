"""The exporters' parameters, declared once and read without importing the exporters.

``sbrdf plugins``, graph validation and the reference docs read these through
each plugin's :class:`~sbrdf_core.plugin.PluginSpec` (``__init__.py``); the
implementations, imported when a graph uses them, take the same tuples as
their ``params``.  This module imports only :mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import Param

#: The GGX conversion's parameters, shared by the converting exporters (materialx, usd, mitsuba; gltf declares
#: its own).
STARTS = Param("starts", "int", 1, "LM starts of the per-texel GGX refit (the start is already the best of a "
               "40-value roughness grid)", bounds=(1, 8))
ITERATIONS = Param("iterations", "int", 8, "LM iterations refining the per-texel GGX refit (0: the grid start alone)",
                   bounds=(0, 1000))
MAX_THETA = Param("max_theta_deg", "float", 70.0, "largest light or view angle from the normal the conversion fits "
                  "and scores (the directions a viewer meets)", bounds=(10.0, 89.0), unit="deg")
FLAG_ERROR = Param("flag_error", "float", 0.25, "texels whose conversion error (cosine-weighted relative RMS on "
                   "held-out directions) is above this are flagged (flagged.png, attrs['flagged'])", bounds=(0.0, None))

EXR_SET = (
    Param("colour_space", "str", "mcallister", "linear RGB primaries of the colour parameters (recorded in the JSON)",
          choices=("mcallister", "rec709", "rec2020")),
    Param("glsl", "bool", True, "also write the model's GLSL (brdf.glsl) and put it in the JSON"),
)

MATERIALX = (
    Param("name", "str", "sbrdf", "material name in the document (node names derive from it)"),
    STARTS,
    ITERATIONS,
    FLAG_ERROR,
    MAX_THETA,
)

MITSUBA = (
    Param("scene", "str", None, "project scene file (YAML, docs/scenes.md) to translate; default: a plane under "
          "a point light (written as scene.yaml)", nullable=True, extra={"path": True}),
    Param("resolution", "list", [256, 192], "image size [width, height] of the default scene", length=2,
          item="int", bounds=(1, 16384)),
    STARTS,
    ITERATIONS,
    FLAG_ERROR,
    MAX_THETA,
)

USD = (
    Param("name", "str", "Material", "the material prim's name"),
    Param("clearcoat", "bool", True, "carry the gloss in UsdPreviewSurface's clearcoat lobe, whose Fresnel can stay "
          "dim at grazing (false: the specular workflow's one lobe, which brightens to white there)"),
    STARTS,
    ITERATIONS,
    FLAG_ERROR,
    MAX_THETA,
)

GLTF = (
    Param("format", "str", "gltf", "gltf: .gltf + .bin + PNG files; glb: one binary file with everything embedded",
          choices=("gltf", "glb")),
    Param("name", "str", "material", "base name of the files written"),
    Param("tile", "int", 64, "texels per side of a conversion tile (one dask block)", bounds=(1, None)),
    Param("starts", "int", 1, "LM starts per texel of the GGX conversion fit (the start is already the best of a "
          "40-value roughness grid)", bounds=(1, None)),
    Param("iterations", "int", 8, "LM iterations refining the GGX conversion fit (0: the grid start alone)",
          bounds=(0, None)),
    Param("anisotropy", "bool", True, "also fit KHR_materials_anisotropy's lobe to a source that may be anisotropic "
          "(written only where some texel gains from it)"),
    Param("flag_error", "float", 0.25, "texels whose conversion error (cosine-weighted relative RMS on held-out "
          "directions) is above this are flagged (<name>_flagged.png, extras.sbrdf.flagged)", bounds=(0.0, None)),
    Param("max_theta_deg", "float", 70.0, "largest light or view angle from the normal the conversion fits and "
          "scores (the directions a viewer meets)", bounds=(10.0, 89.0), unit="deg"),
    Param("source", "str", "params", "what glTF's GGX is fitted to: 'params' = the material's fitted BRDF over the "
          "hemisphere (the conversion); 'samples' = each texel's measured reflectance samples (the Export node's "
          "samples input), fitted with the same LM; isotropic", choices=("params", "samples")),
)
