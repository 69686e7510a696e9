"""The compiled pass of :func:`sbrdf_core.geometry.tile_directions` (numba, cached on disk).

Its own module, imported only where numba is loaded already (geometry itself never imports numba), and
module-level functions: numba's on-disk cache keys a closure by the pickled contents of its cells, and a
dispatcher (``towards`` captured by ``kernel``) pickles differently in every process, so a nested pair would
miss the cache, compile again and add an index entry in every process and every dask worker.  Invariant: no
``cache=True`` kernel here captures a closure variable (tests/core/test_compile_cache.py).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, error_model="numpy")
def towards(points, tx, ty, tz, out, r, store_r, dx, dy, dz, rr):  # pragma: no cover (compiled)
    """One target set's directions (and distances where ``store_r``): per texel, the divisions first in
    planar rows (SIMD lanes; a sample at a time they were scalar), then written as ``(P, 3)`` rows."""
    for t in range(points.shape[0]):
        px, py, pz = points[t, 0], points[t, 1], points[t, 2]
        for p in range(tx.shape[0]):
            # directions_to's arithmetic: d = target − point, r = √(d·d), d / r; d·d summed in the order
            # NumPy's einsum sums three terms (x² + z²) + y², measured to give its bits.
            a, b, c = tx[p] - px, ty[p] - py, tz[p] - pz
            q = np.sqrt((a * a + c * c) + b * b)
            rr[p] = q
            q = q if q != 0.0 else 1.0
            dx[p], dy[p], dz[p] = a / q, b / q, c / q
        for p in range(tx.shape[0]):
            if store_r:
                r[t, p] = rr[p]
            zero = rr[p] == 0.0  # coincident: +z, not NaN
            out[t, p, 0] = 0.0 if zero else dx[p]
            out[t, p, 1] = 0.0 if zero else dy[p]
            out[t, p, 2] = 1.0 if zero else dz[p]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def kernel(points, light, camera):  # pragma: no cover (compiled)
    """``(ω_i (T, P, 3), r (T, P), ω_o (T, P, 3))`` of texel centres ``points (T, 3)`` towards ``light``
    and ``camera`` ``(P, 3)``, all float64 and C-contiguous."""
    T, P = points.shape[0], light.shape[0]
    wi, r, wo = np.empty((T, P, 3)), np.empty((T, P)), np.empty((T, P, 3))
    rows = np.empty(P), np.empty(P), np.empty(P), np.empty(P)
    towards(points, light[:, 0].copy(), light[:, 1].copy(), light[:, 2].copy(), wi, r, True, *rows)
    towards(points, camera[:, 0].copy(), camera[:, 1].copy(), camera[:, 2].copy(), wo, r, False, *rows)
    return wi, r, wo
