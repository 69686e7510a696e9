"""The ``gltf`` exporter's parameters, declared once and read without importing the exporter.

``sbrdf plugins``, graph validation and the reference docs read them through
the exporter's :class:`~sbrdf_core.plugin.PluginSpec` (``__init__.py``);
:class:`.exporter.GLTFExporter`, imported when a graph exports, takes the same
tuple as its ``params``.  This module imports only :mod:`sbrdf_core.params`
(not the GGX conversion of :mod:`sbrdf_lib.convert`).
"""

from __future__ import annotations

from sbrdf_core.params import Param

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
