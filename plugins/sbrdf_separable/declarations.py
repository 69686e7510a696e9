"""The separable plugin's parameters, declared once and read without importing the decompositions.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each contribution
(``__init__.py``); the implementations (:mod:`.fitters`, :mod:`.model`,
:mod:`.parameterizations`), imported when a graph uses them, take the same
tuples as their ``params``.  This module imports only :mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import REQUIRED, Param

MAP_PARAM = Param("map", "str", "xy", "how a unit vector becomes texture coordinates: XY hemisphere map or parabolic "
                  "map (Eq 5)", choices=("xy", "parabolic"))
#: The parameterizations' parameters (all four take the same).
PARAMETERIZATION = (MAP_PARAM,)

#: Parameters both decompositions take.
COMMON = (
    Param("factors", "str", REQUIRED, "path of the SeparableFactors store to write, inside the graph's store beside "
          "the artifacts (e.g. <store>/nd.zarr; relative to the graph file); the fitted model reads it from there. "
          "Only a SeparableFactors store there is ever replaced", extra={"path": True, "output": True}),
    Param("parameterization", "str", "gram-schmidt", "change of variables (a parameterization plugin)",
          extra={"plugin_category": "parameterization"}),
    MAP_PARAM,
    Param("size", "int", 32, "factor texture size K (K x K texels per factor)", bounds=(2, 1024)),
    Param("terms", "int", 1, "number of terms N", bounds=(1, 64)),
    Param("clamp_max", "float", None, "limit the BRDF to [0, clamp_max] before decomposing (the text uses 5)",
          bounds=(0.0, None), nullable=True, unit="sr^-1"),
    Param("encoding", "str", "float32", "factor storage: float textures, or 8-bit with per-factor scale/bias "
          "(signed factors biased, seed 001 §6.1)", choices=("float32", "float16", "unorm8")),
    Param("neighbours", "int", 4, "samples blended (inverse distance) per factor-grid point", bounds=(1, 64)),
    Param("impute", "int", 1, "passes that fill grid points below the horizon with the current estimate",
          bounds=(0, 100)),
)

SVD = COMMON + (
    Param("solver", "str", "arpack", "ARPACK (the first N singular triples) or a dense LAPACK SVD of the whole matrix",
          choices=("dense", "arpack")),
)

ND = COMMON + (
    Param("p", "float", 2.0, "exponent of the p-norm normalizing each row", bounds=(1e-3, None)),
    Param("refine", "int", 1, "power-iteration passes per residual term (signs the rows; 0 = the text's ND)",
          bounds=(0, 100)),
)

SEPARABLE = (
    Param("factors", "str", None, "path of the SeparableFactors store (null: one constant term, scale/pi)",
          nullable=True),
    Param("terms", "int", None, "use the first N terms only (null: all stored)", bounds=(1, None), nullable=True),
)
