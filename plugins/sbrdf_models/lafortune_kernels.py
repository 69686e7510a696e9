"""The compiled projection of packed Lafortune fit-form rows onto a texel's limits.

:meth:`~sbrdf_models.lafortune_fit.LafortuneFitForm.constrain_packed` calls it
where a fit left its limits (the peak a lobe may reach anywhere on the
hemisphere, the sharpness the samples resolve): the same numbers as
:meth:`~sbrdf_models.lafortune_fit.LafortuneFitForm.constrain`, which the tests
compare it with.  Packed layout (as :meth:`LafortuneFitForm.pack`):
``rho_d[C]``, per lobe ``rho_s[C], c_x[, c_y], log_exponent``, then ``beta``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

LOG_CAP = 60.0


@njit(cache=True, nogil=True, error_model="numpy")
def _project_row(v, lo, hi, peak, has_peak, n_cap, growth, s2, c2, n_lo, n_hi, rho_at, c_at, ln_at, C, work):
    """:func:`constrain_packed` on one packed row ``v``, in place (``work``: (4, L) scratch)."""
    K = v.shape[0]
    L, A = c_at.shape
    r_scale, c_scale, n_new, peaks = work[0], work[1], work[2], work[3]
    for k in range(K):
        v[k] = min(max(v[k], lo[k]), hi[k])
    budget = np.inf
    if has_peak:
        rmax_d = -np.inf
        for c in range(C):
            v[c] = min(v[c], peak)
            rmax_d = max(rmax_d, v[c])
        budget = max(peak - rmax_d, 0.0)
    finite = budget < np.inf
    total = 0.0
    for j in range(L):
        n = math.exp(v[ln_at[j]])
        nn = min(max(min(n, n_cap), n_lo), n_hi)
        rmax = -np.inf
        for c in range(C):
            rmax = max(rmax, v[rho_at[j] + c])
        rs = budget / (rmax if rmax > 0.0 else 1.0) if rmax > budget else 1.0
        r = rmax * rs
        log_m = math.log(budget / r) / nn if (r > 0.0 and finite) else np.inf
        if growth >= 0.0:
            log_m = min(log_m, math.log(max(growth, 1.0)) / nn)
        m_allowed = math.exp(min(log_m, 50.0))
        c_allowed = max((m_allowed - c2) / s2, 1.0)
        cabs = 0.0
        for a in range(A):
            cabs = max(cabs, abs(v[c_at[j, a]]))
        cs = c_allowed / (cabs if cabs > 0.0 else 1.0) if cabs > c_allowed else 1.0
        m = max(1.0, cabs * cs * s2 + c2)
        peaks[j] = r * math.exp(min(nn * math.log(m), 700.0))
        total += peaks[j]
        r_scale[j], c_scale[j], n_new[j] = rs, cs, nn
    share = budget / (total if total > 0.0 else 1.0) if total > budget else 1.0
    for j in range(L):
        scale = r_scale[j] * share
        for c in range(C):
            v[rho_at[j] + c] *= scale
        for a in range(A):
            v[c_at[j, a]] *= c_scale[j]
        v[ln_at[j]] = math.log(n_new[j])


@njit(cache=True, nogil=True, error_model="numpy")
def constrain_packed(x, lo, hi, peak, has_peak, n_cap, growth, s2, c2, n_lo, n_hi, rho_at, c_at, ln_at, C):
    """:meth:`LafortuneFitForm.constrain` on packed fit-form rows ``x`` ``(T, K)``, returned as a new array.

    The same steps in the same order (``BRDFModel.constrain``'s clip to the
    bounds ``lo``/``hi`` and ρ_d ≤ peak, then ``bound_lobes`` per lobe and
    the lobes' common share), one texel at a time.  Why: LM projects every
    trial point, and the NumPy version costs about half a millisecond a call
    in dict packing and small array passes whatever the number of texels, a
    tenth of a Fit tile.  ``peak`` ``(T,)`` (read where ``has_peak``),
    ``n_cap`` ``(T,)`` the resolvable exponent (inf: no bound); ``rho_at``, ``ln_at`` ``(L,)`` the packed offsets of each
    lobe's ρ_s and log n, ``c_at`` ``(L, A)`` of its C_x (, C_y).  ``growth`` < 0:
    no grazing bound.  Equal to the NumPy path to a few ulp (libm's exp and
    log against NumPy's).
    """
    T, K = x.shape
    L = c_at.shape[0]
    out = np.empty_like(x)
    work = np.empty((4, L))
    for t in range(T):
        for k in range(K):
            out[t, k] = x[t, k]
        _project_row(out[t], lo, hi, peak[t], has_peak, n_cap[t], growth, s2, c2, n_lo, n_hi, rho_at, c_at, ln_at, C,
                     work)
    return out
