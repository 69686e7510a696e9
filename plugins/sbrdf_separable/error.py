"""The error measure of seed 001 §5.2: cosine-weighted RMS of outgoing radiance over Monte Carlo pairs.

Parameterization-independent: n direction pairs drawn uniformly (in solid
angle) over the incident and view hemispheres, each value the BRDF times
cos θ_i (the radiance a unit irradiance from ω_i sends to ω_o), compared in
luminance (Fig 5 plots luminance error) or per RGB channel.  8000 pairs, as
in the text; the pairs are seeded, so every approximation of a study is
measured on the same ones.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sbrdf_core.brdf import luminance_weights
from sbrdf_core.brdf_checks import hemisphere_directions

PAIRS = 8000
#: §6.1's range limit; the study compares every approximation against the BRDF limited the same way.
CLAMP = 5.0
#: The study's BRDFs (§5.2): the text's anisotropic Ward, a copper-like Cook–Torrance, a velvet.
STUDY: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "ward": ("ward", {"anisotropic": True}, {"rho_d": [1 / np.pi, 0, 0], "rho_s": [0.3] * 3, "alpha_x": [0.21],
                                             "alpha_y": [0.048]}),
    "copper": ("cook-torrance", {"distribution": "beckmann"}, {"rho_d": [0, 0, 0], "f0": [0.95, 0.64, 0.54],
                                                               "alpha": [0.3]}),
    "velvet": ("velvet", {}, {"rho_d": [0.05, 0.02, 0.02], "rho_s": [0.8, 0.3, 0.3], "sigma": [0.35]}),
}


def study_brdf(name: str, registry=None):
    """One of :data:`STUDY` as ``f(wi, wo) -> (..., 3)``, limited to [0, :data:`CLAMP`]."""
    from sbrdf_core.registry import default_registry

    from .sources import model_function

    model, cfg, params = STUDY[name]
    f = model_function((registry or default_registry()).create("brdf-model", model, cfg), params)
    return lambda wi, wo: np.clip(f(wi, wo), 0.0, CLAMP)


def mc_pairs(n: int = PAIRS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return hemisphere_directions(rng, (n,)), hemisphere_directions(rng, (n,))


def radiance_rms(reference, approx, n: int = PAIRS, seed: int = 0, colour_space: str | None = "rec709") -> float:
    """RMS of (f_approx − f_ref) cos θ_i over ``n`` uniform pairs; luminance, or RGB pooled if ``colour_space`` is None.

    ``reference`` and ``approx`` are functions ``f(wi, wo) -> (M, 3)``.
    """
    wi, wo = mc_pairs(n, seed)
    d = (np.asarray(approx(wi, wo)) - np.asarray(reference(wi, wo))) * wi[:, 2:3]
    if colour_space is not None:
        d = d @ luminance_weights(colour_space)
    return float(np.sqrt(np.mean(d * d)))


def factors_function(factors):
    """``f(wi, wo)`` of a :class:`~.factors.Factors` (through the ``separable`` model's own lookup)."""
    from .model import SeparableModel

    m = SeparableModel()
    m.set_factors(factors)
    ones = {"scale": np.ones((1, 3))}
    return lambda wi, wo: m.eval(ones, np.asarray(wi)[None], np.asarray(wo)[None])[0]
