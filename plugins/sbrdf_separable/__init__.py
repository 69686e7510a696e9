"""Separable BRDF approximations (Kautz & McCool 1999, seed 001).

Contributes the ``parameterization`` plugins (standard, elevation-azimuth,
rusinkiewicz, gram-schmidt), the ``separable`` BRDF model (factor textures),
the ``velvet`` model (a deep-microgeometry test BRDF), and the ``svd`` and
``nd`` fitters.  See docs/separable.md.
"""

from sbrdf_core.params import REQUIRED, Param
from sbrdf_core.plugin import PluginSpec, hookimpl

from .model import PARAMS as SEPARABLE_PARAMS
from .parameterizations import MAP_PARAM

_COMMON = (
    Param("factors", "str", REQUIRED, "path of the SeparableFactors store to write (local; relative to the graph file); "
          "the fitted model reads it from there", extra={"path": True}),
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
SVD_PARAMS = _COMMON + (
    Param("solver", "str", "arpack", "ARPACK (the first N singular triples) or a dense LAPACK SVD of the whole matrix",
          choices=("dense", "arpack")),
)
ND_PARAMS = _COMMON + (
    Param("p", "float", 2.0, "exponent of the p-norm normalizing each row", bounds=(1e-3, None)),
    Param("refine", "int", 1, "power-iteration passes per residual term (signs the rows; 0 = the text's ND)",
          bounds=(0, 100)),
)


@hookimpl
def sbrdf_parameterizations():
    m = "sbrdf_separable.parameterizations"
    return [
        PluginSpec("standard", f"{m}:Standard", (MAP_PARAM,), summary="incident/view: (theta_i, phi_i) x (theta_o, phi_o)"),
        PluginSpec("elevation-azimuth", f"{m}:ElevationAzimuth", (MAP_PARAM,),
                   summary="(theta_i, theta_o) x (phi_i, phi_o), angles on the texture, phi periodic"),
        PluginSpec("rusinkiewicz", f"{m}:Rusinkiewicz", (MAP_PARAM,),
                   summary="halfway h x difference d in a frame from the normal (unstable at h = n)"),
        PluginSpec("gram-schmidt", f"{m}:GramSchmidt", (MAP_PARAM,),
                   summary="halfway h x difference d in a frame from the tangent (Eq 4, 6)"),
    ]


@hookimpl
def sbrdf_brdf_models():
    return [
        PluginSpec("separable", "sbrdf_separable.model:SeparableModel", SEPARABLE_PARAMS,
                   summary="sum of products of 2D factor textures (SVD or normalized decomposition)"),
        PluginSpec("velvet", "sbrdf_separable.velvet:VelvetModel",
                   summary="Ashikhmin-Premoze distribution-based velvet (inverted-Gaussian fibre slopes)"),
    ]


@hookimpl
def sbrdf_fitters():
    return [
        PluginSpec("svd", "sbrdf_separable.fitters:SVDFitter", SVD_PARAMS,
                   summary="separable BRDF by truncated SVD of the sampled K^2 x K^2 matrix (one material)"),
        PluginSpec("nd", "sbrdf_separable.fitters:NDFitter", ND_PARAMS,
                   summary="separable BRDF by normalized decomposition, streamed (one material)"),
    ]
