"""The quantizers' parameters, declared once and read without importing the quantizers.

``sbrdf plugins``, graph validation and the reference docs read these through
each plugin's :class:`~sbrdf_core.plugin.PluginSpec` (``__init__.py``); the
implementations, imported when a graph uses them, take the same tuples as
their ``params``.  This module imports only :mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import Param

LINEAR = (
    Param("dtype", "str", "uint8", "texel storage type", choices=("uint8", "uint16", "float16", "float32")),
)

FLOAT_EXR = (
    Param("dtype", "str", "float16", "float32 (exact) or half float", choices=("float16", "float32")),
    Param("colour_space", "str", "mcallister", "linear RGB primaries the material is in (recorded in the JSON)",
          choices=("mcallister", "rec709", "rec2020")),
)

FIXED16 = (
    Param("canonical", "bool", False, "store the model's canonical parameters (Lafortune: C_z = 1)"),
)

MCALLISTER8 = (
    Param("rescale", "str", "max", "per-texel rho_s/C gauge: max(rho_s) = 1, min(rho_s) = min|C|, or as fitted",
          choices=("max", "balanced", "none")),
    Param("c_range", "float", 1.0, "C biased over -1..1 (7 bits) or -2..2 (6 bits, keeps |C| > 1)",
          choices=(1.0, 2.0)),
    Param("alpha", "str", None, "transparency mask: a PNG of the texel grid (0 = cut away) stored as "
          "rho_d's alpha; relative to the graph file", nullable=True, extra={"path": True}),
)

PALETTE = (
    Param("k", "int", 256, "palette entries at most (8-bit index)", bounds=(1, 256)),
    Param("directions", "int", 12, "Fibonacci directions per side of the sampled-BRDF vectors", bounds=(2, 64)),
    Param("seed", "int", 0, "k-means seed"),
)
