"""Procedural parameter maps: smooth waves plus a checker, for simulated materials with a known truth.

One definition shared by everything that invents a ground-truth material
(the ``synthetic`` capture source, the virtual camera's default maps, the
fitters' sample model), so the same texel gets the same value everywhere.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pattern"]


def pattern(n_u: int, n_v: int, index: int, channel: int) -> np.ndarray:
    """Smooth waves plus a 4×4 checker, in [0, 1], different per parameter and channel."""
    u = (np.arange(n_u) + 0.5) / n_u
    v = (np.arange(n_v) + 0.5) / n_v
    uu, vv = np.meshgrid(u, v)
    waves = 0.5 + 0.25 * np.sin(2 * np.pi * ((1 + index) * uu + channel / 3)) * np.cos(2 * np.pi * (1 + channel) * vv)
    checker = ((np.floor(uu * 4) + np.floor(vv * 4)) % 2) * 0.5 - 0.25
    return np.clip(waves + 0.8 * checker * (0.5 if index else 1.0), 0.0, 1.0)
