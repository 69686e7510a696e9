"""Linearization: acquired light-arc images -> a shading map (seed 002 §3.2, Eq 1).

Each acquired image j (light at elevation θ_j, unit intensity) holds per texel
the value b_j = f_r·cos θ_j that the material sends to the camera; its average
over the texels and colour channels is a_j.  The shading map has N slices
whose averages rise linearly,

    r_i = i · a_max / (N − 1),  i = 0 .. N − 1          (Eq 1)

and slice i interpolates linearly between the two acquired images whose
averages bracket r_i.  Because an average is linear, slice i's average is r_i
exactly.  A black image (a = 0, the light at the horizon) is added to the
acquired ones, so slice 0 is black and slices below the dimmest acquisition
interpolate towards it.

The resampling is one ``(N, P)`` matrix W applied to the ``(P, V, U, C)``
stack, so it runs lazily in dask (``einsum``) without a per-texel loop.
"""

from __future__ import annotations

import numpy as np


def image_averages(images: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Average of each image over its valid texels and the colour channels: ``(P,)``.

    >>> image_averages(np.ones((2, 3, 4, 3)) * np.array([1.0, 2.0])[:, None, None, None])
    array([1., 2.])
    """
    images = np.asarray(images, np.float64)
    if valid is None:
        return images.mean(axis=(1, 2, 3))
    ok = np.asarray(valid, bool)[..., None] & np.isfinite(images)
    n = ok.sum(axis=(1, 2, 3))
    return np.where(n > 0, np.where(ok, images, 0.0).sum(axis=(1, 2, 3)) / np.maximum(n, 1), 0.0)


def slice_averages(a_max: float, slices: int) -> np.ndarray:
    """Eq 1: ``r_i = i a_max / (N − 1)``."""
    return np.arange(slices) * (a_max / (slices - 1))


def interpolation_weights(averages: np.ndarray, slices: int = 8) -> np.ndarray:
    """The ``(N, P)`` matrix W with ``slice_i = Σ_j W[i, j] image_j`` (Eq 1 and the bracketing interpolation).

    Images with a non-finite or non-positive average get no weight.  All weights of slice 0
    are zero (the added black image).

    >>> interpolation_weights(np.array([2.0, 1.0]), 3)
    array([[0., 0.],
           [0., 1.],
           [1., 0.]])
    """
    if slices < 2:
        raise ValueError(f"a shading map needs at least 2 slices, got {slices}")
    a = np.asarray(averages, np.float64).reshape(-1)
    usable = np.isfinite(a) & (a > 0)
    W = np.zeros((slices, a.size))
    if not usable.any():
        return W
    idx = np.flatnonzero(usable)
    order = idx[np.argsort(a[idx], kind="stable")]
    A = np.concatenate([[0.0], a[order]])            # the black image first
    r = slice_averages(A[-1], slices)
    hi = np.clip(np.searchsorted(A, r, side="left"), 1, len(A) - 1)
    lo = hi - 1
    span = A[hi] - A[lo]
    w = np.clip(np.where(span > 0, (r - A[lo]) / np.where(span > 0, span, 1.0), 1.0), 0.0, 1.0)
    cols = np.concatenate([[-1], order])             # column -1 = the black image, dropped
    rows = np.arange(slices)
    for k, weight in ((lo, 1.0 - w), (hi, w)):
        keep = cols[k] >= 0
        np.add.at(W, (rows[keep], cols[k][keep]), weight[keep])
    return W


def linearize(images: np.ndarray, slices: int = 8, valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eager version: ``(P, V, U, C)`` BRDF·cos images -> ``(shading map (N, V, U, C), r (N,), a (P,))``."""
    a = image_averages(images, valid)
    W = interpolation_weights(a, slices)
    ok = np.isfinite(images) if valid is None else np.asarray(valid, bool)[..., None] & np.isfinite(images)
    filled = np.where(ok, images, a[:, None, None, None])
    return np.einsum("np,pvuc->nvuc", W, filled), slice_averages(a.max(initial=0.0), slices), a
