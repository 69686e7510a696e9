"""What a decomposition samples: a BRDF-model plugin evaluated on the fly, or measured samples interpolated.

Both are functions ``f(wi, wo) -> (M, 3)`` sr⁻¹ of direction pairs in the
surface frame, so :mod:`.decompose` never needs to know which it has.

Measured samples (a 1 × 1-texel SampledReflectance: a gonioreflectometer
table or a sampled model) are scattered, while the factor grid is regular:
:class:`ScatteredBRDF` interpolates them by inverse-distance weighting of the
k nearest samples in the parameterization's own 4D coordinates (x, y), where
a near-specular lobe is compact.  Each sample is entered twice, as
(ω_i, ω_o) and (ω_o, ω_i) (reciprocity doubles the coverage); invalid and
non-finite samples are dropped first.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


def model_function(model, params: Mapping[str, np.ndarray]):
    """``f(wi, wo)`` of one texel's parameters of a BRDF-model plugin."""
    params = {k: np.asarray(v, float).reshape(1, -1) for k, v in params.items()}

    def f(wi, wo):
        return model.eval(params, np.asarray(wi, float)[None], np.asarray(wo, float)[None])[0]

    return f


class ScatteredBRDF:
    """Inverse-distance-weighted k-nearest-neighbour interpolation of scattered BRDF samples.

    Parameters
    ----------
    wi, wo
        ``(S, 3)`` directions of the samples.
    f_r
        ``(S, 3)`` values, sr⁻¹.
    valid
        ``(S,)`` usable samples (non-finite values are dropped too).
    param
        The parameterization whose coordinates measure distance.
    neighbours
        k of the k-NN (1 = nearest sample).
    """

    def __init__(self, wi, wo, f_r, valid, param, neighbours: int = 4):
        from scipy.spatial import cKDTree

        wi, wo, f_r = (np.asarray(a, float).reshape(-1, 3) for a in (wi, wo, f_r))
        valid = np.asarray(valid, bool).reshape(-1) & np.isfinite(f_r).all(axis=1)
        valid &= np.isfinite(wi).all(axis=1) & np.isfinite(wo).all(axis=1) & (wi[:, 2] > 0) & (wo[:, 2] > 0)
        if not valid.any():
            raise ValueError("no valid BRDF samples above the horizon to decompose (all invalid, non-finite or below)")
        wi, wo, f_r = wi[valid], wo[valid], f_r[valid]
        self.param, self.samples = param, int(valid.sum())
        self.values = np.concatenate([f_r, f_r])
        self.tree = cKDTree(self._coords(np.concatenate([wi, wo]), np.concatenate([wo, wi])))
        self.k = int(min(max(neighbours, 1), len(self.values)))

    def _coords(self, wi, wo):
        x, y = self.param.coords(wi, wo)
        return np.concatenate([x, y], axis=-1)

    def __call__(self, wi, wo):
        wi, wo = np.asarray(wi, float).reshape(-1, 3), np.asarray(wo, float).reshape(-1, 3)
        dist, idx = self.tree.query(self._coords(wi, wo), k=self.k)
        if self.k == 1:
            return self.values[idx]
        w = 1.0 / np.maximum(dist, 1e-9) ** 2
        w /= w.sum(axis=1, keepdims=True)
        return np.einsum("mk,mkc->mc", w, self.values[idx])
