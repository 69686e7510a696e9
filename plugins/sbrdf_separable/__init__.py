"""Separable BRDF approximations (Kautz & McCool 1999, seed 001).

Contributes the ``parameterization`` plugins (standard, elevation-azimuth,
rusinkiewicz, gram-schmidt), the ``separable`` BRDF model (factor textures),
the ``velvet`` model (a deep-microgeometry test BRDF), and the ``svd`` and
``nd`` fitters.  See docs/separable.md.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_parameterizations():
    m = "sbrdf_separable.parameterizations"
    return [
        PluginSpec("standard", f"{m}:Standard", params=declarations.PARAMETERIZATION,
                   summary="incident/view: (theta_i, phi_i) x (theta_o, phi_o)"),
        PluginSpec("elevation-azimuth", f"{m}:ElevationAzimuth", params=declarations.PARAMETERIZATION,
                   summary="(theta_i, theta_o) x (phi_i, phi_o), angles on the texture, phi periodic"),
        PluginSpec("rusinkiewicz", f"{m}:Rusinkiewicz", params=declarations.PARAMETERIZATION,
                   summary="halfway h x difference d in a frame from the normal (unstable at h = n)"),
        PluginSpec("gram-schmidt", f"{m}:GramSchmidt", params=declarations.PARAMETERIZATION,
                   summary="halfway h x difference d in a frame from the tangent (Eq 4, 6)"),
    ]


@hookimpl
def sbrdf_brdf_models():
    return [
        PluginSpec("separable", "sbrdf_separable.model:SeparableModel", params=declarations.SEPARABLE,
                   summary="sum of products of 2D factor textures (SVD or normalized decomposition)"),
        PluginSpec("velvet", "sbrdf_separable.velvet:VelvetModel", params=(),
                   summary="Ashikhmin-Premoze distribution-based velvet (inverted-Gaussian fibre slopes)"),
    ]


@hookimpl
def sbrdf_fitters():
    return [
        PluginSpec("svd", "sbrdf_separable.fitters:SVDFitter", params=declarations.SVD,
                   summary="separable BRDF by truncated SVD of the sampled K^2 x K^2 matrix (one material)"),
        PluginSpec("nd", "sbrdf_separable.fitters:NDFitter", params=declarations.ND,
                   summary="separable BRDF by normalized decomposition, streamed (one material)"),
    ]
