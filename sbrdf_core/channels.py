"""Reductions over the trailing colour axis (RGB), written as one elementwise operation per channel.

Why: NumPy reduces a short last axis (length 3) one tiny row at a time, so
``np.isfinite(f_r).all(axis=-1)`` or ``f_r.max(axis=-1)`` over a Fit tile's
``(1024, 300, 3)`` samples costs several times what the same operation channel
by channel does, and the Fit node makes several such passes per tile.  The results are the same bits
as the reductions they replace (a NaN's sign bit aside): the same operations in the same order.
"""

from __future__ import annotations

import functools

import numpy as np

from ._compiled import worth_compiling

__all__ = ["abs_channel_mean", "all_finite", "channel_max", "channel_mean"]


def all_finite(a: np.ndarray) -> np.ndarray:
    """``np.isfinite(a).all(axis=-1)``: every channel of each sample finite."""
    a = np.asarray(a)
    if a.shape[-1] == 0:
        return np.ones(a.shape[:-1], bool)
    out = np.isfinite(a[..., 0])
    for c in range(1, a.shape[-1]):
        out &= np.isfinite(a[..., c])
    return out


def channel_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=-1)`` (NaN propagates, as there; its sign bit may differ)."""
    a = np.asarray(a)
    out = a[..., 0].copy()
    for c in range(1, a.shape[-1]):
        np.maximum(out, a[..., c], out=out)
    return out


def channel_mean(a: np.ndarray) -> np.ndarray:
    """``a.mean(axis=-1)`` for a floating ``a``: the channels summed in order, then divided by their count."""
    a = np.asarray(a)
    out = a[..., 0] + 0.0  # a copy; and NumPy's sum of -0.0s is +0.0
    for c in range(1, a.shape[-1]):
        out += a[..., c]
    return out / a.shape[-1]


def abs_channel_mean(a: np.ndarray) -> np.ndarray:
    """``channel_mean(np.abs(a))``; one compiled pass without the ``|a|`` copy where the work is large
    enough (:func:`sbrdf_core._compiled.worth_compiling`) and ``a`` is a float64 ``(T, S, C)`` array (the shot-noise weights' level of a Fit tile: the copy costs more than
    the sum)."""
    a = np.asarray(a)
    if worth_compiling(a.size) and a.ndim == 3 and a.dtype == np.float64 and a.shape[-1] > 0:
        return _compiled_abs_channel_mean()(a)
    return channel_mean(np.abs(a))


@functools.cache
def _compiled_abs_channel_mean():
    """:func:`abs_channel_mean`'s kernel (numba, cached on disk): :func:`channel_mean`'s order of operations."""
    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(a):  # pragma: no cover (compiled)
        T, S, C = a.shape
        out = np.empty((T, S))
        for t in range(T):
            for s in range(S):
                acc = abs(a[t, s, 0]) + 0.0
                for c in range(1, C):
                    acc += abs(a[t, s, c])
                out[t, s] = acc / C
        return out

    return kernel
