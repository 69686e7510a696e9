"""The two artifact kinds of decoupled mesostructure (Kautz et al. 2003, seed 002).

Declared here, beside the node kinds that write them, and contributed through
the ``sbrdf_artifact_kinds`` hook, so ``open_artifact`` and ``sbrdf info`` know
them.  Both are renderable: ``material`` names the adapter
(:func:`sbrdf_shading.surface.open_surface`) the ``cpu`` and ``gl`` renderers
shade a scene material through (a shading map is a material).
"""

from __future__ import annotations

from sbrdf_core.artifacts import ArraySpec, ArtifactKind

ShadingMap = ArtifactKind(
    "ShadingMap",
    1,
    "A stack of N slices whose average 'BRDF times cosine' value rises linearly from 0 to a_max (seed 002 Eq 1), "
    "looked up per texel with r = sigma f_r cos theta_i. Attributes: a_max, slices, source images, filled samples.",
    (
        ArraySpec("slices", "NVUC", "float32", "shading map: slice i has average r_i = i a_max / (N-1), sr^-1"),
        ArraySpec("slice_average", "N", "float64", "r_i of each slice (Eq 1), sr^-1"),
        ArraySpec("image_average", "P", "float64", "average a_j of each acquired image, sr^-1 (BRDF times cosine)"),
        ArraySpec("theta_i_deg", "P", "float64", "light elevation from the normal of each acquired image, degrees"),
    ),
    material="sbrdf_shading.surface:open_surface",
)

PowerShadingMap = ArtifactKind(
    "PowerShadingMap",
    1,
    "A shading map compressed per texel and colour channel to f(x) = k_s x^K, x = r / a_max (seed 002 Eq 4). "
    "Attributes: a_max, slices, rms (overall), exponent search steps.",
    (
        ArraySpec("k_s", "VUC", "float32", "value of the brightest slice, sr^-1"),
        ArraySpec("exponent", "VUC", "float32", "fitted exponent K"),
        ArraySpec("rms", "VU", "float32", "RMS of fit minus shading map over the texel's slices and channels, sr^-1"),
    ),
    material="sbrdf_shading.surface:open_surface",
)

KINDS = (ShadingMap, PowerShadingMap)

