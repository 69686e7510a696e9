"""Compiled normal equations for fitting Lafortune lobes (the fit form: C_z = 1, log n).

The NumPy path (:class:`sbrdf_core.least_squares.LeastSquaresProblem`)
materialises a ``(T, S, 3, K)`` Jacobian whose colour columns are mostly
zeros; at 65 536 texels × 400 samples that costs ~5 ms per texel.  Here each
texel accumulates, sample by sample and in parallel over texels, the Gram
matrix of a small channel-free basis (1, s_j, ∂s_j/∂shape): every Jacobian
entry is such a basis value times 1 or a lobe's ρ_s,c, so ``JᵀJ`` and ``Jᵀr``
follow per texel by a K×m mapping.  Same numbers (tests compare both paths),
a fraction of the work per sample.  Packed layout (as :meth:`LafortuneFitForm.pack`):
``rho_d[C]``, per lobe ``rho_s[C], c_x[, c_y], log_exponent``, then ``beta``.
"""

from __future__ import annotations

import math
import threading

import numba
import numpy as np
from numba import njit, prange

LOG_CAP = 60.0


@njit(cache=True, inline="always")
def _unpack(x, t, lobes, aniso, has_beta, C, rho, cx, cy, n):
    """Texel t's packed fit-form row -> local per-lobe arrays; returns (cos β, sin β)."""
    K = x.shape[1]
    k = C
    for j in range(lobes):
        rho[j] = x[t, k:k + C]
        cx[j] = x[t, k + C]
        cy[j] = x[t, k + C + 1] if aniso else cx[j]
        n[j] = math.exp(x[t, k + C + 1 + aniso])
        k += C + 2 + aniso
    if has_beta:
        return math.cos(x[t, K - 1]), math.sin(x[t, K - 1])
    return 1.0, 0.0


@njit(cache=True, inline="always")
def _basis(ix, iy, iz, ox, oy, oz, lobes, aniso, has_beta, cb, sb, cx, cy, n, rho, rho_d, C, pred, b):
    """Prediction (C,) for one sample and its channel-free basis ``b``.

    ``b = [1, s_1..s_L, per lobe: ∂s/∂c (1 or 2), ∂s/∂log n (, ∂s/∂β)]``: every
    Jacobian entry is one of these times 1 or a lobe's ρ_s,c (see ``_assemble``).
    Parameters arrive unpacked in local arrays (``cx``, ``cy``, ``n`` per lobe,
    ``rho`` (L, C)) so the sample loop reads no parameter memory.
    """
    for c in range(C):
        pred[c] = rho_d[c]
    if has_beta:
        ix, iy = cb * ix + sb * iy, -sb * ix + cb * iy
        ox, oy = cb * ox + sb * oy, -sb * ox + cb * oy
    pxx, pyy, pzz = ix * ox, iy * oy, iz * oz
    ns = 2 + aniso + has_beta
    for j in range(lobes):
        dot = cx[j] * pxx + cy[j] * pyy + pzz
        s = 0.0
        dsdx = 0.0
        lx = 0.0
        if dot > 0.0:
            lx = math.log(dot)
            s = math.exp(min(n[j] * lx, LOG_CAP))
            dsdx = n[j] * s / dot
        for c in range(C):
            pred[c] += rho[j, c] * s
        b[1 + j] = s
        q = 1 + lobes + j * ns
        if aniso:
            b[q] = dsdx * pxx
            b[q + 1] = dsdx * pyy
        else:
            b[q] = dsdx * (pxx + pyy)
        b[q + 1 + aniso] = s * lx * n[j]
        if has_beta:
            b[q + 2 + aniso] = dsdx * (cx[j] - cy[j]) * (iy * ox + ix * oy)


@njit(cache=True, inline="always")
def _assemble(x, t, G, H, lobes, aniso, has_beta, C, K, M, A, g):
    """``JᵀJ = Σ_c M_c G M_cᵀ`` and ``Jᵀr = Σ_c M_c H_c`` with M_c mapping basis -> parameters."""
    m = G.shape[0]
    ns = 2 + aniso + has_beta
    for c in range(C):
        for p in range(K):
            for i in range(m):
                M[p, i] = 0.0
        M[c, 0] = 1.0  # rho_d,c
        k = C
        for j in range(lobes):
            rho = x[t, k + c]
            M[k + c, 1 + j] = 1.0  # rho_s,j,c
            q = 1 + lobes + j * ns
            for a in range(1 + aniso + 1):  # c_x (, c_y), log n
                M[k + C + a, q + a] = rho
            if has_beta:
                M[K - 1, q + 2 + aniso] = rho
            k += C + 2 + aniso
        for p in range(K):
            acc = 0.0
            for i in range(m):
                acc += M[p, i] * H[i, c]
            g[t, p] += acc
            for r in range(p, K):
                acc = 0.0
                for i in range(m):
                    if M[p, i] == 0.0:
                        continue
                    for l in range(m):
                        acc += M[p, i] * G[i, l] * M[r, l]
                A[t, p, r] += acc
    for p in range(K):
        for r in range(p):
            A[t, p, r] = A[t, r, p]


@njit(parallel=True, cache=True)
def normal_equations(x, idx, wi, wo, f, w, lobes, aniso, has_beta):
    """``(JᵀJ (T,K,K), Jᵀr (T,K), cost (T,))`` for parameter rows ``x`` of texels ``idx``.

    Reading the data through ``idx`` (instead of copying ``wi[idx]`` ...) keeps
    the per-iteration cost to the texels still active.
    """
    T, K = x.shape
    S = wi.shape[1]
    C = f.shape[2]
    m = 1 + lobes + lobes * (2 + aniso + has_beta)
    A = np.zeros((T, K, K))
    g = np.zeros((T, K))
    cost = np.zeros(T)
    for t in prange(T):
        d = idx[t]
        pred = np.empty(C)
        b = np.zeros(m)
        b[0] = 1.0
        G = np.zeros((m, m))
        H = np.zeros((m, C))
        rho_d = x[t, :C].copy()
        rho = np.empty((max(lobes, 1), C))
        cx, cy, n = np.empty(max(lobes, 1)), np.empty(max(lobes, 1)), np.empty(max(lobes, 1))
        cb, sb = _unpack(x, t, lobes, aniso, has_beta, C, rho, cx, cy, n)
        total = 0.0
        for s in range(S):
            ws = w[d, s]
            if ws == 0.0:
                continue
            iz, oz = wi[d, s, 2], wo[d, s, 2]
            if iz <= 0.0 or oz <= 0.0:
                for c in range(C):  # below the horizon the model is 0: residual −f, no gradient
                    r = -f[d, s, c] * ws
                    total += r * r
                continue
            _basis(wi[d, s, 0], wi[d, s, 1], iz, wo[d, s, 0], wo[d, s, 1], oz, lobes, aniso, has_beta, cb, sb,
                   cx, cy, n, rho, rho_d, C, pred, b)
            w2 = ws * ws
            for c in range(C):
                r = (pred[c] - f[d, s, c]) * ws
                total += r * r
                for i in range(m):
                    H[i, c] += b[i] * r * ws
            for i in range(m):
                bi = b[i] * w2
                for l in range(i, m):
                    G[i, l] += bi * b[l]
        cost[t] = total
        for i in range(m):
            for l in range(i):
                G[i, l] = G[l, i]
        _assemble(x, t, G, H, lobes, aniso, has_beta, C, K, np.empty((K, m)), A, g)
    return A, g, cost


@njit(parallel=True, cache=True)
def scan_first_exponent(x, log_exponents, wi, wo, f, w, lobes, aniso, has_beta):
    """Starting point: for each texel, the lobe-1 exponent from ``log_exponents`` with the smallest cost.

    For every candidate the lobe magnitudes are solved by least squares (ρ_d
    and the other lobes' shapes held at ``x``), clipped to ≥ 0, and the cost
    follows in closed form from the same sums: one pass over the samples per
    candidate.  Returns the updated fit-form rows.
    """
    T, K = x.shape
    S = wi.shape[1]
    C = f.shape[2]
    out = x.copy()
    kn1 = C + C + 1 + aniso  # index of log_exponent_1
    for t in prange(T):
        best = np.inf
        cx, cy, n, rho0 = np.empty(lobes), np.empty(lobes), np.empty(lobes), np.empty((lobes, C))
        cb, sb = _unpack(x, t, lobes, aniso, has_beta, C, rho0, cx, cy, n)
        sv = np.empty(lobes)
        for q in range(log_exponents.size):
            n[0] = math.exp(log_exponents[q])
            G = np.zeros((lobes, lobes))
            h = np.zeros((lobes, C))
            e0 = 0.0
            for s in range(S):
                ws = w[t, s]
                if ws == 0.0:
                    continue
                iz, oz = wi[t, s, 2], wo[t, s, 2]
                if iz <= 0.0 or oz <= 0.0:
                    for c in range(C):
                        e0 += (f[t, s, c] * ws) ** 2
                    continue
                ix, iy, ox, oy = wi[t, s, 0], wi[t, s, 1], wo[t, s, 0], wo[t, s, 1]
                if has_beta:
                    ix, iy = cb * ix + sb * iy, -sb * ix + cb * iy
                    ox, oy = cb * ox + sb * oy, -sb * ox + cb * oy
                for j in range(lobes):
                    dot = cx[j] * ix * ox + cy[j] * iy * oy + iz * oz
                    sv[j] = math.exp(min(n[j] * math.log(dot), LOG_CAP)) * ws if dot > 0.0 else 0.0
                for c in range(C):
                    r0 = (f[t, s, c] - x[t, c]) * ws
                    e0 += r0 * r0
                    for j in range(lobes):
                        h[j, c] += sv[j] * r0
                for j in range(lobes):
                    for i in range(lobes):
                        G[j, i] += sv[j] * sv[i]
            for j in range(lobes):
                G[j, j] += 1e-12
            rho = np.linalg.solve(G, h)
            cost = e0
            for c in range(C):
                for j in range(lobes):
                    rho[j, c] = min(max(rho[j, c], 0.0), 1e6) if np.isfinite(rho[j, c]) else 0.0
                for j in range(lobes):
                    cost -= 2.0 * rho[j, c] * h[j, c]
                    for i in range(lobes):
                        cost += rho[j, c] * G[j, i] * rho[i, c]
            if cost < best:
                best = cost
                out[t, kn1] = log_exponents[q]
                k = C
                for j in range(lobes):
                    for c in range(C):
                        out[t, k + c] = rho[j, c]
                    k += C + 2 + aniso
    return out


_LAYER_LOCK = threading.Lock()
_serialise: bool | None = None  # unknown until the first parallel call has picked a threading layer


def run_parallel(kernel, *args):
    """Call a ``parallel=True`` kernel safely from dask's worker threads.

    Numba's OpenMP and TBB layers accept concurrent calls; its fallback
    ``workqueue`` layer (no libgomp or tbb on the machine) aborts the process
    when two threads enter it at once, so calls are serialised there.
    """
    global _serialise
    if _serialise is False:
        return kernel(*args)
    with _LAYER_LOCK:
        out = kernel(*args)
        _serialise = numba.threading_layer() == "workqueue"
        return out


class CompiledLafortuneProblem:
    """:class:`~sbrdf_core.least_squares.LeastSquaresProblem` for the Lafortune fit form, compiled."""

    def __init__(self, form, f_r, weight, wi, wo):
        self.form = form
        self.f_r = np.ascontiguousarray(f_r, dtype=np.float64)
        self.weight = np.ascontiguousarray(weight, dtype=np.float64)
        self.wi = np.ascontiguousarray(wi, dtype=np.float64)
        self.wo = np.ascontiguousarray(wo, dtype=np.float64)
        self.flags = (form.lobes, int(form.anisotropic), bool(form.has_beta))

    def data_energy(self):
        wf = self.f_r * self.weight[..., None]
        return np.einsum("tsc,tsc->t", wf, wf)

    def normal_equations(self, x, idx):
        return run_parallel(normal_equations, np.ascontiguousarray(x, dtype=np.float64),
                            np.ascontiguousarray(idx, dtype=np.int64), self.wi, self.wo, self.f_r, self.weight,
                            *self.flags)
