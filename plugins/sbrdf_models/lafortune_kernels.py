"""The projection of packed Lafortune fit-form rows onto a texel's limits, as a kernel.

The fitting engine compiles :func:`project_kernel` into its loop and projects
every iterate with it, and the starting points through it
(:func:`sbrdf_core.engine.project`).  Its bounds are the peak a lobe may reach
anywhere on the hemisphere and the sharpness the samples resolve: the same numbers as
:meth:`~sbrdf_models.lafortune_fit.LafortuneFitForm.constrain`, which the tests
compare it with.  Packed layout (as :meth:`LafortuneFitForm.pack`):
``rho_d[C]``, per lobe ``rho_s[C], c_x[, c_y], log_exponent``, then ``beta``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .lafortune_bounds import EXPONENT_BOUNDS

#: Per-texel values :func:`project_kernel` reads (``LafortuneFitForm.project_limits``), in this order.
LIMITS = ("peak", "has_peak", "n_cap", "growth", "sin2_max_theta", "cos2_max_theta")


@njit(cache=True, nogil=True, error_model="numpy")
def _bound_lobe(x, at, C, A, budget, n_cap, growth, s2, c2, scales):
    """One lobe of :func:`project_kernel` (its ρ_s at ``x[at]``, then C and log n): the exponent capped, ρ_s
    within the budget, |C| within what the peak allows at the horizon.  Writes ``scales`` = (ρ_s scale, C scale,
    new n) and returns the lobe's peak."""
    n_lo, n_hi = EXPONENT_BOUNDS
    n = math.exp(x[at + C + A])
    nn = min(max(min(n, n_cap), n_lo), n_hi)
    rmax = -np.inf
    for c in range(C):
        rmax = max(rmax, x[at + c])
    rs = budget / (rmax if rmax > 0.0 else 1.0) if rmax > budget else 1.0
    r = rmax * rs
    log_m = math.log(budget / r) / nn if (r > 0.0 and budget < np.inf) else np.inf
    if growth >= 0.0:
        log_m = min(log_m, math.log(max(growth, 1.0)) / nn)
    m_allowed = math.exp(min(log_m, 50.0))
    # at a horizon of 0° only C_z = 1 counts: no bound on C
    c_allowed = max((m_allowed - c2) / s2, 1.0) if s2 > 0.0 else np.inf
    cabs = 0.0
    for a in range(A):
        cabs = max(cabs, abs(x[at + C + a]))
    cs = c_allowed / (cabs if cabs > 0.0 else 1.0) if cabs > c_allowed else 1.0
    m = max(1.0, cabs * cs * s2 + c2)
    scales[0], scales[1], scales[2] = rs, cs, nn
    return r * math.exp(min(nn * math.log(m), 700.0))


def project_kernel(x, cfg, lim, lo, hi):
    """:meth:`LafortuneFitForm.constrain` on one packed row ``x``, in place: the fitting engine's projection.

    The same steps in the same order: ``BRDFModel.constrain``'s clip to the box ``lo``/``hi`` and ρ_d ≤ peak,
    then ``bound_lobes`` per lobe and the lobes' common share.  ``cfg`` = (lobes, anisotropic, beta), ``lim``
    the :data:`LIMITS` of the texel (growth < 0: no grazing bound).  Equal to the NumPy path to a few ulp
    (libm's exp and log against NumPy's).  Returns True.
    """
    K = x.shape[0]
    L, A, C = int(cfg[0]), 2 if cfg[1] != 0.0 else 1, 3
    peak, has_peak, n_cap, growth, s2, c2 = lim[0], lim[1] != 0.0, lim[2], lim[3], lim[4], lim[5]
    work = np.empty((3, L))  # per lobe: ρ_s scale, C scale, new n
    r_scale, c_scale, n_new = work[0], work[1], work[2]
    for k in range(K):
        x[k] = min(max(x[k], lo[k]), hi[k])
    budget = np.inf
    if has_peak:
        rmax_d = -np.inf
        for c in range(C):
            x[c] = min(x[c], peak)
            rmax_d = max(rmax_d, x[c])
        budget = max(peak - rmax_d, 0.0)
    total = 0.0
    for j in range(L):
        total += _bound_lobe(x, C + j * (C + A + 1), C, A, budget, n_cap, growth, s2, c2, work[:, j])
    share = budget / (total if total > 0.0 else 1.0) if total > budget else 1.0
    for j in range(L):
        at = C + j * (C + A + 1)
        scale = r_scale[j] * share
        for c in range(C):
            x[at + c] *= scale
        for a in range(A):
            x[at + C + a] *= c_scale[j]
        x[at + C + A] = math.log(n_new[j])
    return True
