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
import os
import threading

import numba
import numpy as np
from numba import njit, prange

LOG_CAP = 60.0

# Every kernel callable from Python is ``nogil=True``, so a dask thread inside one never keeps the Fit node's
# other threads out of Python.  numba already releases the GIL inside a ``parallel=True`` kernel's parallel
# region; the flag covers the serial kernels (:func:`constrain_packed`) and the serial code around a ``prange``.
# Safe because every kernel here is nopython code on arrays the caller owns for the call (a tile's own
# problem): no Python objects, no shared mutable state.  Concurrent calls of a ``parallel=True`` kernel are
# safe on numba's OpenMP and TBB layers and serialised on the workqueue layer by :func:`run_parallel`.
# ``inline="always"`` helpers are only called from compiled code, where the flag has no effect.

# OpenMP workers that spin while waiting for the next parallel region burn CPU time that no fit uses (a quarter
# of the fit's CPU time on a shared 2-core machine, measured); waiting passively costs microseconds of latency.
# Read by libgomp when numba's OpenMP layer starts (the first parallel call), so setting it here is in time;
# a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


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


@njit(parallel=True, cache=True, nogil=True)
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


#: Samples per block of :func:`normal_equations_isotropic`: a scan's 300-700 poses in one or two blocks.  Each
#: block pays every row's loop set-up and its SIMD lanes' final sum: at 64, a texel's normal equations took 6.8 µs
#: at 2 lobes on benchmarks/fit.py's data (one thread), at 512 5.7, and 5.4 with the Gram taken two rows at a time;
#: the block's dozen rows (up to 60 KB) stay in L2.
SAMPLE_BLOCK = 512
#: Texels a task of :func:`normal_equations_isotropic` takes in turn, reusing its scratch arrays.
TEXEL_CHUNK = 16

# log and exp in SIMD lanes: fdlibm's e_log.c and e_exp.c (the algorithms and coefficients musl and FreeBSD use; under
# 1 ulp), written as loops over arrays of plain arithmetic so LLVM vectorises them, which it cannot do for libm's
# calls.  fdlibm: "Copyright (C) 1993 by Sun Microsystems, Inc. All rights reserved.  Developed at SunPro, a Sun
# Microsystems, Inc. business.  Permission to use, copy, modify, and distribute this software is freely granted,
# provided that this notice is preserved."
_LN2_HI, _LN2_LO, _INV_LN2 = 6.93147180369123816490e-01, 1.90821492927058770002e-10, 1.44269504088896338700e+00
_LG = (6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01, 2.222219843214978396e-01,
       1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01)
_P = (1.66666666666666019037e-01, -2.77777777770155933842e-03, 6.61375632143793436117e-05,
      -1.65339022054652515390e-06, 4.13813679705723846039e-08)
_SQRT2 = 1.4142135623730951


@njit(cache=True, nogil=True, fastmath={"contract"}, error_model="numpy")
def simd_log(x, out, mant, expo, nb):
    """``out[:nb] = log(x[:nb])`` for positive normal ``x`` (the caller keeps the rest out); ``mant``, ``expo``:
    scratch of the same length (float64, int64).  ``error_model="numpy"``: no zero-division branch to stop SIMD."""
    lg1, lg2, lg3, lg4, lg5, lg6, lg7 = _LG
    bits = x.view(np.int64)
    mbits = mant.view(np.int64)
    for k in range(nb):  # x = 2^e · m, m in [1, 2)
        b = bits[k]
        mbits[k] = (b & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000
        expo[k] = (b >> 52) - 1023
    for k in range(nb):
        m = mant[k]
        e = np.float64(expo[k])
        big = m > _SQRT2  # m in [√2/2, √2): log(1 + f) with |f| small
        m = m * 0.5 if big else m
        e = e + (1.0 if big else 0.0)
        f = m - 1.0
        hfsq = 0.5 * f * f
        s = f / (2.0 + f)
        z = s * s
        w = z * z
        t1 = w * (lg2 + w * (lg4 + w * lg6))
        t2 = z * (lg1 + w * (lg3 + w * (lg5 + w * lg7)))
        out[k] = s * (hfsq + t2 + t1) + e * _LN2_LO - hfsq + f + e * _LN2_HI


@njit(cache=True, nogil=True, fastmath={"contract"}, error_model="numpy")
def simd_exp(y, out, scale, expo, nb):
    """``out[:nb] = exp(y[:nb])`` for ``y`` ≤ 709; 0 at or below -708, NaN for NaN; ``scale``, ``expo``: scratch."""
    p1, p2, p3, p4, p5 = _P
    for k in range(nb):  # y = k ln 2 + r, |r| ≤ ln2 / 2
        x = y[k]
        x = x if x > -708.0 else -708.0
        kf = np.floor(x * _INV_LN2 + 0.5)
        hi = x - kf * _LN2_HI
        lo = kf * _LN2_LO
        r = hi - lo
        rr = r * r
        c = r - rr * (p1 + rr * (p2 + rr * (p3 + rr * (p4 + rr * p5))))
        out[k] = 1.0 + (r * c / (2.0 - c) - lo + hi)
        expo[k] = np.int64(kf) + 1023
    sbits = scale.view(np.int64)
    for k in range(nb):  # 2^k
        sbits[k] = expo[k] << 52
    for k in range(nb):
        yk = y[k]
        out[k] = out[k] * scale[k] if yk > -708.0 else (0.0 if yk <= -708.0 else yk)


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _gram_block(Bw, Rw, nb, G, H):
    """``G += Bw Bwᵀ`` (its upper triangle), ``H += Bw Rwᵀ`` over a block's ``nb`` samples: each sum runs along a
    contiguous row, so it is done in SIMD lanes (``reassoc`` lets the sum be split across them; the order of the
    additions changes, not what is added).  Rows are taken two at a time, so each other row is read once for both:
    half the passes over the block (2 lobes: 25 instead of 49)."""
    m, C = Bw.shape[0], Rw.shape[0]
    i = 0
    while i + 1 < m:
        b0, b1 = Bw[i], Bw[i + 1]
        a00, a01, a11 = 0.0, 0.0, 0.0
        for k in range(nb):
            u, v = b0[k], b1[k]
            a00 += u * u
            a01 += u * v
            a11 += v * v
        G[i, i] += a00
        G[i, i + 1] += a01
        G[i + 1, i + 1] += a11
        for l in range(i + 2, m):
            _pair_sums(b0, b1, Bw[l], nb, G, i, l)
        for c in range(C):
            _pair_sums(b0, b1, Rw[c], nb, H, i, c)
        i += 2
    if i < m:  # an odd row last
        bi = Bw[i]
        G[i, i] += _dot(bi, bi, nb)
        for c in range(C):
            H[i, c] += _dot(bi, Rw[c], nb)


@njit(cache=True, fastmath={"reassoc", "contract"}, inline="always")
def _pair_sums(b0, b1, other, nb, out, i, col):
    """``out[i, col] += Σ b0·other``, ``out[i + 1, col] += Σ b1·other`` over ``nb`` entries, ``other`` read once."""
    a0, a1 = 0.0, 0.0
    for k in range(nb):
        w = other[k]
        a0 += b0[k] * w
        a1 += b1[k] * w
    out[i, col] += a0
    out[i + 1, col] += a1


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _weigh_residuals(Rw, W, nb, store):
    """Σ_c Σ_k (Rw[c, k]·W[k])² over a block, and (``store``) the weighted residuals written back into ``Rw``.

    Why: summed one by one the squares are a chain of dependent adds, a third of the cost-only kernel's time;
    ``reassoc`` lets the sum be split across SIMD lanes (the order of the additions changes, not what is added;
    the normal equations and :func:`cost_isotropic` both sum here, so their costs stay equal to the bit)."""
    total = 0.0
    for c in range(Rw.shape[0]):
        rc = Rw[c]
        acc = 0.0
        for k in range(nb):
            r = rc[k] * W[k]
            if store:
                rc[k] = r
            acc += r * r
        total += acc
    return total


@njit(cache=True, nogil=True, error_model="numpy")
def _lobe_values(cj, nj, P, Z, nb, dot, lx, y, sv, scratch, expo):
    """One isotropic lobe (C_xy ``cj``, n ``nj``) over a block of ``nb`` samples: ``sv`` = max(0, x)^n with
    x = C_xy·pxy + pzz (0 where x ≤ 0), ``dot`` = x (1 where x ≤ 0) and ``lx`` = log ``dot``, which its derivatives
    reuse (:func:`_lobe_rows`).  s = exp(n log x), the log and exp in SIMD lanes (:func:`simd_log`,
    :func:`simd_exp`)."""
    for k in range(nb):
        xk = cj * P[k] + Z[k]
        dot[k] = xk if xk > 1e-300 else 1.0
    simd_log(dot, lx, scratch, expo, nb)
    for k in range(nb):
        yk = nj * lx[k]
        y[k] = yk if yk < LOG_CAP else LOG_CAP
    simd_exp(y, sv, scratch, expo, nb)
    for k in range(nb):
        sv[k] = sv[k] if cj * P[k] + Z[k] > 1e-300 else 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _lobe_rows(cj, nj, P, Z, W, nb, dot, lx, sv, bs, bc, bn, derivatives):
    """The weighted basis rows of a lobe from its :func:`_lobe_values`: s·w, ∂s/∂C_xy·w = n s pxy / x·w and
    ∂s/∂log n·w = n s log x·w (zeros without ``derivatives``)."""
    for k in range(nb):
        s_ = sv[k]
        wk = W[k]
        bs[k] = s_ * wk
        if derivatives:
            bc[k] = nj * s_ * P[k] / dot[k] * wk
            bn[k] = nj * s_ * (lx[k] if cj * P[k] + Z[k] > 1e-300 else 0.0) * wk
        else:
            bc[k] = 0.0
            bn[k] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _lobe(cj, nj, P, Z, W, nb, dot, lx, y, sv, scratch, expo, bs, bc, bn, derivatives):
    """:func:`_lobe_values` then :func:`_lobe_rows`: a lobe's weighted basis rows over a block in one call."""
    _lobe_values(cj, nj, P, Z, nb, dot, lx, y, sv, scratch, expo)
    _lobe_rows(cj, nj, P, Z, W, nb, dot, lx, sv, bs, bc, bn, derivatives)


@njit(cache=True, inline="always")
def _assemble_isotropic(x, t, G, H, lobes, C, K, basis_of, coef, A, g):
    """``JᵀJ[p, r] = G[b(p), b(r)] Σ_c a_c(p) a_c(r)``, ``Jᵀr[p] = Σ_c a_c(p) H[b(p), c]``: parameter p's Jacobian
    column in channel c is basis function b(p) times a_c(p) (1 or 0 for a magnitude, the lobe's ρ_s,c for a shape).
    :func:`_assemble`'s result for isotropic lobes without β, without its K × m mapping matrices."""
    for p in range(K):
        for c in range(C):
            coef[c, p] = 0.0
    for c in range(C):
        basis_of[c] = 0  # rho_d,c
        coef[c, c] = 1.0
    k = C
    for j in range(lobes):
        for c in range(C):
            basis_of[k + c] = 1 + j  # rho_s,j,c
            coef[c, k + c] = 1.0
        q = 1 + lobes + 2 * j
        basis_of[k + C], basis_of[k + C + 1] = q, q + 1  # c_xy, log n
        for c in range(C):
            coef[c, k + C] = coef[c, k + C + 1] = x[t, k + c]
        k += C + 2
    for p in range(K):
        bp = basis_of[p]
        acc = 0.0
        for c in range(C):
            acc += coef[c, p] * H[bp, c]
        g[t, p] = acc
        for r in range(p, K):
            a = 0.0
            for c in range(C):
                a += coef[c, p] * coef[c, r]
            A[t, p, r] = A[t, r, p] = G[bp, basis_of[r]] * a


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def normal_equations_isotropic(x, idx, pxy, pzz, w_lit, f_t, e_unlit, lobes):
    """:func:`normal_equations` for isotropic lobes without β (the usual 1-2 lobe fit), in SIMD lanes.

    Why: the sample-by-sample kernel spends its time in scalar libm calls and a
    chain of scalar adds.  Here the data come as the problem prepared them once
    (:class:`CompiledLafortuneProblem`: ω_i,xy·ω_o,xy, ω_i,z·ω_o,z, the weight
    where the sample is lit, f_r channel-major, each texel's unlit energy), a
    block of :data:`SAMPLE_BLOCK` samples is worked row by row, the log and exp
    are :func:`simd_log` and :func:`simd_exp`, the sums :func:`_gram_block`.
    80 → 30 ns CPU per sample at 2 lobes (measured); equal to the sample-by-
    sample kernel to about 1e-13 relative (the same terms, summed in another order).
    """
    T, K = x.shape
    C = f_t.shape[1]
    A = np.zeros((T, K, K))
    g = np.zeros((T, K))
    cost = np.zeros(T)
    for chunk in prange((T + TEXEL_CHUNK - 1) // TEXEL_CHUNK):
        work = _ne_scratch(K, C, lobes, pxy.shape[1])
        for t in range(chunk * TEXEL_CHUNK, min(T, (chunk + 1) * TEXEL_CHUNK)):
            cost[t] = _texel_normal_equations(x, t, idx[t], pxy, pzz, w_lit, f_t, e_unlit, lobes, A, g, *work)
    return A, g, cost


@njit(cache=True, nogil=True)
def _ne_scratch(K, C, lobes, S):
    """The working arrays of :func:`_texel_normal_equations`, made once per task and reused texel after texel:
    a block's basis rows, and every block's residual rows and lobe values (:func:`_texel_values` keeps them for
    :func:`_texel_gram`)."""
    m = 1 + 3 * lobes
    L = max(lobes, 1)
    B = max(1, min(SAMPLE_BLOCK, S))  # a block's length, no longer than the samples
    blocks = max(1, (S + SAMPLE_BLOCK - 1) // SAMPLE_BLOCK)
    return (np.zeros((m, m)), np.zeros((m, C)), np.zeros((m, B)), np.zeros((blocks, C, B)),
            np.ones((blocks, 3 * L, B)), np.zeros(B), np.zeros(B), np.zeros(B, np.int64), np.zeros(K, np.int64),
            np.zeros((C, K)), np.empty((L, C)), np.empty(L), np.empty(L), np.empty(L))


@njit(cache=True, nogil=True, error_model="numpy")
def _texel_normal_equations(x, t, d, pxy, pzz, w_lit, f_t, e_unlit, lobes, A, g, G, H, Bw, Rw, V, y, scratch, expo,
                            basis_of, coef, rho, cx, cy, n):
    """Row ``t`` of :func:`normal_equations_isotropic` (parameters ``x[t]``, the data of texel ``d``): writes
    ``A[t]``, ``g[t]``, returns the cost.  :func:`_texel_values` then :func:`_texel_gram`."""
    total = _texel_values(x, t, d, pxy, pzz, w_lit, f_t, e_unlit, lobes, Rw, V, y, scratch, expo, rho, cx, cy, n)
    _texel_gram(x, t, d, pxy, pzz, w_lit, lobes, A, g, G, H, Bw, Rw, V, basis_of, coef, cx, n)
    return total


@njit(cache=True, nogil=True, error_model="numpy")
def _texel_values(x, t, d, pxy, pzz, w_lit, f_t, e_unlit, lobes, Rw, V, y, scratch, expo, rho, cx, cy, n):
    """Texel ``d``'s cost at parameters ``x[t]``, keeping what its normal equations need: per block ``b``, the
    weighted residuals ``Rw[b]`` (a row per channel) and each lobe's values ``V[b]`` (rows 3j, 3j + 1, 3j + 2:
    s, x, log x; :func:`_lobe_values`).  Why apart from :func:`_texel_gram`: LM needs only the cost of a trial
    step it rejects, and of the one it stops at."""
    S = pxy.shape[1]
    C = f_t.shape[1]
    _unpack(x, t, lobes, 0, False, C, rho, cx, cy, n)
    total = e_unlit[d]
    for s0 in range(0, S, SAMPLE_BLOCK):
        nb = min(SAMPLE_BLOCK, S - s0)
        R, Vb = Rw[s0 // SAMPLE_BLOCK], V[s0 // SAMPLE_BLOCK]
        W = _block_values(x, t, d, s0, nb, pxy, pzz, w_lit, f_t, lobes, R, Vb, y, scratch, expo, rho, cx, n)
        total += _weigh_residuals(R, W, nb, True)
    return total


@njit(cache=True, nogil=True, error_model="numpy")
def _texel_gram(x, t, d, pxy, pzz, w_lit, lobes, A, g, G, H, Bw, Rw, V, basis_of, coef, cx, n):
    """``A[t]``, ``g[t]`` from what :func:`_texel_values` left at the same parameters: ``Bw`` holds a block's basis
    b times the sample's weight, a row per basis function (:func:`_lobe_rows`), summed by :func:`_gram_block`."""
    S = pxy.shape[1]
    C = Rw.shape[1]
    K = x.shape[1]
    m = G.shape[0]
    G[:] = 0.0
    H[:] = 0.0
    for s0 in range(0, S, SAMPLE_BLOCK):
        nb = min(SAMPLE_BLOCK, S - s0)
        Vb = V[s0 // SAMPLE_BLOCK]
        P, Z, W = pxy[d, s0:s0 + nb], pzz[d, s0:s0 + nb], w_lit[d, s0:s0 + nb]
        b0 = Bw[0]
        for k in range(nb):
            b0[k] = W[k]
        for j in range(lobes):
            q = 1 + lobes + 2 * j
            _lobe_rows(cx[j], n[j], P, Z, W, nb, Vb[3 * j + 1], Vb[3 * j + 2], Vb[3 * j], Bw[1 + j], Bw[q], Bw[q + 1],
                       True)
        _gram_block(Bw, Rw[s0 // SAMPLE_BLOCK], nb, G, H)
    for i in range(m):
        for l in range(i):
            G[i, l] = G[l, i]
    _assemble_isotropic(x, t, G, H, lobes, C, K, basis_of, coef, A, g)


@njit(cache=True, nogil=True, error_model="numpy")
def _block_values(x, t, d, s0, nb, pxy, pzz, w_lit, f_t, lobes, Rw, V, y, scratch, expo, rho, cx, n):
    """Texel ``d``'s samples ``s0:s0 + nb`` at parameters ``x[t]`` (unpacked in ``rho``, ``cx``, ``n``): the
    prediction minus f_r in ``Rw`` (a row per channel, not yet weighted) and each lobe's values in ``V`` (rows
    3j, 3j + 1, 3j + 2: :func:`_lobe_values`' s, x and log x).  Returns the block's weights."""
    C = f_t.shape[1]
    P, Z, W = pxy[d, s0:s0 + nb], pzz[d, s0:s0 + nb], w_lit[d, s0:s0 + nb]
    for c in range(C):
        fc, rc, rd = f_t[d, c, s0:s0 + nb], Rw[c], x[t, c]
        for k in range(nb):
            rc[k] = rd - fc[k]
    for j in range(lobes):
        sv = V[3 * j]
        _lobe_values(cx[j], n[j], P, Z, nb, V[3 * j + 1], V[3 * j + 2], y, sv, scratch, expo)
        for c in range(C):
            rc, rj = Rw[c], rho[j, c]
            for k in range(nb):
                rc[k] += rj * sv[k]
    return W


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def cost_isotropic(x, idx, pxy, pzz, w_lit, f_t, e_unlit, lobes):
    """The ``cost`` of :func:`normal_equations_isotropic` alone, from the same prepared data: no derivative rows, no
    Gram sums.  Why: the fit's last step (its unweighted cost, when it minimised a weighted one) and the scoring of
    starting points need only the cost, and paid for the whole normal equations (about 2.5× the work, measured)."""
    T, K = x.shape
    C = f_t.shape[1]
    cost = np.zeros(T)
    for chunk in prange((T + TEXEL_CHUNK - 1) // TEXEL_CHUNK):
        _, _, _, Rw, V, y, scratch, expo, _, _, rho, cx, cy, n = _ne_scratch(K, C, lobes, pxy.shape[1])
        for t in range(chunk * TEXEL_CHUNK, min(T, (chunk + 1) * TEXEL_CHUNK)):
            cost[t] = _texel_values(x, t, idx[t], pxy, pzz, w_lit, f_t, e_unlit, lobes, Rw, V, y, scratch, expo, rho,
                                    cx, cy, n)
    return cost


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


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lm_isotropic(x0, wi, wo, w, f, lobes, lo, hi, free, has_limits, peak, has_peak,
                 n_cap, growth, s2, c2, n_lo, n_hi, rho_at, c_at, ln_at, iterations, tolerance, damping, max_damping,
                 exact, max_step):
    """:func:`sbrdf_lib.lm.levenberg_marquardt` for isotropic lobes without β, each texel's whole solve compiled.

    The same iteration, step for step: Marquardt's diagonal scaling, the
    clip to ``lo``/``hi``, the projection onto the limits
    (:func:`_project_row`, where ``has_limits``) with the active-set re-solve
    of parameters it pinned, each step shortened to ``max_step`` ``(K,)``
    (:func:`_limit_step`), λ / 3 on success and × 4 on failure, and the
    same stopping tests (``exact``: the fraction of the data's energy below
    which a fit counts as exact).  Why: run batched in NumPy, each iteration
    paid array passes and calls whatever the number of texels still active,
    most of a tile's time outside the normal equations.  Returns ``(x, cost,
    converged)``.  The data come as the problem holds them (ω_i, ω_o, the
    weights ``w``, f_r); each texel's samples are prepared as its solve starts
    (:func:`_prepare_texel`), into the task's scratch rows, instead of a whole
    tile's prepared copy made first and read back from memory.
    Damped systems are solved by :func:`_solve` (a singular one: no step).
    A trial step is scored by its cost alone (:func:`_texel_values`); its
    normal equations (:func:`_texel_gram`, from the values kept) are summed
    only when LM goes on from it: rejected steps and the last step need none
    (at 2 lobes on benchmarks/fit.py's data 1.4 of 7.6 evaluations a texel;
    42.7 → 39.2 µs a texel, one thread, the same iterates to the bit).
    """
    T, K = x0.shape
    S, C = f.shape[1], f.shape[2]
    L = max(c_at.shape[0], 1)
    x_out = np.empty_like(x0)
    cost_out = np.empty(T)
    converged = np.zeros(T, np.bool_)
    for chunk in prange((T + TEXEL_CHUNK - 1) // TEXEL_CHUNK):
        work = _ne_scratch(K, C, lobes, S)
        G, H, Bw, Rw, V, y, scratch, expo, basis_of, coef, rho, cx, cy, n = work
        # The texel's prepared samples (prepare_isotropic's rows), made as it starts, while they are in cache.
        pxy, pzz, w_lit, f_t, e_unlit = np.empty((1, S)), np.empty((1, S)), np.empty((1, S)), np.empty((1, C, S)), \
            np.empty(1)
        pwork = np.empty((4, L))
        xc, xn = np.empty((1, K)), np.empty((1, K))
        Ac, gc = np.empty((1, K, K)), np.empty((1, K))
        M, b, diag, raw, step = np.empty((K, K)), np.empty(K), np.empty(K), np.empty(K), np.empty(K)
        keep = np.empty(K, np.bool_)
        for t in range(chunk * TEXEL_CHUNK, min(T, (chunk + 1) * TEXEL_CHUNK)):
            e_unlit[0], energy, weighted = _prepare_texel(wi, wo, w, f, t, pxy, pzz, w_lit, f_t, 0)
            for k in range(K):
                xc[0, k] = min(max(x0[t, k], lo[k]), hi[k])
            if has_limits:
                _project_row(xc[0], lo, hi, peak[t], has_peak, n_cap[t], growth, s2, c2, n_lo, n_hi, rho_at, c_at,
                             ln_at, C, pwork)
            cost = _texel_normal_equations(xc, 0, 0, pxy, pzz, w_lit, f_t, e_unlit, lobes, Ac, gc, *work)
            _mask_free(Ac, gc, free)
            active = weighted and cost > 0.0 and np.isfinite(cost)
            lam = damping
            for _ in range(iterations):
                if not active:
                    break
                for k in range(K):
                    diag[k] = max(Ac[0, k, k], 1e-12) if free[k] else 1.0
                _damped_step(Ac, gc, diag, lam, keep, M, b, raw, False)
                _limit_step(raw, max_step)
                for k in range(K):
                    xn[0, k] = min(max(xc[0, k] + raw[k], lo[k]), hi[k])
                    step[k] = raw[k]
                if has_limits:
                    _project_row(xn[0], lo, hi, peak[t], has_peak, n_cap[t], growth, s2, c2, n_lo, n_hi, rho_at,
                                 c_at, ln_at, C, pwork)
                    pinned = False  # held by the projection where the step pointed out: solve again without them
                    for k in range(K):
                        scale = 1e-9 * max(abs(xc[0, k]), 1.0)
                        held = (abs(xn[0, k] - (xc[0, k] + raw[k])) > scale and abs(xn[0, k] - xc[0, k]) <= scale
                                and free[k])
                        keep[k] = free[k] and not held
                        pinned = pinned or held
                    if pinned:
                        _damped_step(Ac, gc, diag, lam, keep, M, b, raw, True)
                        _limit_step(raw, max_step)
                        for k in range(K):
                            xn[0, k] = min(max(xc[0, k] + raw[k], lo[k]), hi[k])
                        _project_row(xn[0], lo, hi, peak[t], has_peak, n_cap[t], growth, s2, c2, n_lo, n_hi, rho_at,
                                     c_at, ln_at, C, pwork)
                    for k in range(K):
                        step[k] = xn[0, k] - xc[0, k]
                # The trial's cost first; its normal equations only if LM goes on from it (not for a rejected
                # step, nor for the step it stops at): the same iterates, a fifth fewer Gram sums.
                cost_new = _texel_values(xn, 0, 0, pxy, pzz, w_lit, f_t, e_unlit, lobes, Rw, V, y, scratch, expo, rho,
                                         cx, cy, n)
                better = np.isfinite(cost_new) and cost_new < cost
                gain = (cost - cost_new) / max(cost, 1e-300) if better else 0.0
                step_max, x_max = 0.0, 0.0
                for k in range(K):
                    step_max = max(step_max, abs(step[k]))
                    x_max = max(x_max, abs(xc[0, k]))
                negligible = step_max <= 1e-9 * max(x_max, 1e-12)
                if better:
                    xc[:] = xn
                    cost = cost_new
                    lam = max(lam / 3.0, 1e-12)
                else:
                    lam = lam * 4.0
                if ((better and gain < tolerance) or (not better and negligible) or lam > max_damping
                        or cost <= exact * energy):
                    active = False
                elif better:
                    _texel_gram(xc, 0, 0, pxy, pzz, w_lit, lobes, Ac, gc, G, H, Bw, Rw, V, basis_of, coef, cx, n)
                    _mask_free(Ac, gc, free)
            x_out[t] = xc[0]
            cost_out[t] = cost
            converged[t] = not active
    return x_out, cost_out, converged


@njit(cache=True, inline="always")
def _limit_step(raw, max_step):
    """:func:`sbrdf_lib.lm.limit_step` on one step, in place (the same scale, so the same bits)."""
    scale = 1.0
    for k in range(raw.shape[0]):
        size = abs(raw[k])
        if size > max_step[k]:
            scale = min(scale, max_step[k] / size)
    if scale < 1.0:
        for k in range(raw.shape[0]):
            raw[k] *= scale


@njit(cache=True, inline="always")
def _mask_free(A, g, free):
    """Zero the rows and columns of ``A[0]`` and the entries of ``g[0]`` of parameters not ``free``."""
    K = g.shape[1]
    for i in range(K):
        if not free[i]:
            g[0, i] = 0.0
            for j in range(K):
                A[0, i, j] = 0.0
                A[0, j, i] = 0.0


@njit(cache=True, inline="always")
def _damped_step(A, g, diag, lam, keep, M, b, out, reduced):
    """``out = −(A + λ·diag)⁻¹ g`` (0 where not finite, or everywhere if singular); ``reduced``: only the ``keep``
    parameters move (the others' rows and columns replaced by the identity, their gradient by 0)."""
    K = g.shape[1]
    for i in range(K):
        ki = keep[i] if reduced else True
        for j in range(K):
            if reduced and not (ki and keep[j]):
                M[i, j] = 1.0 if i == j else 0.0
            else:
                M[i, j] = A[0, i, j]
        M[i, i] += lam * (diag[i] if ki else 1.0)
        b[i] = -g[0, i] if ki else 0.0
    ok = _solve(M, b, K)
    for i in range(K):
        v = b[i] if ok else 0.0
        out[i] = v if np.isfinite(v) and (keep[i] or not reduced) else 0.0


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def eval_lobes(rho_d, rho_s, c_x, c_y, c_z, n, wi, wo):
    """:meth:`LafortuneModel.eval` without β: ``ρ_d + Σ_j ρ_s,j max(0, C_j·(ω_i ⊙ ω_o))^n_j`` above the horizon,
    0 below, ``(T, S, C)``.  The same arithmetic in the same order as the NumPy path; the log and exp in SIMD
    lanes (:func:`simd_log`, :func:`simd_exp`, within an ulp of NumPy's; results under e^-708 flush to 0).  Why:
    the NumPy path's passes over ``(T, S)`` and ``(T, S, 3)`` arrays were a tenth of a Fit tile (its RMS)."""
    T, S, _ = wi.shape
    C = rho_d.shape[1]
    out = np.empty((T, S, C))
    for chunk in prange((T + TEXEL_CHUNK - 1) // TEXEL_CHUNK):
        work = _prediction_scratch(C, S)
        f = work[-1]
        for t in range(chunk * TEXEL_CHUNK, min(T, (chunk + 1) * TEXEL_CHUNK)):
            for s0 in range(0, S, SAMPLE_BLOCK):
                nb = min(SAMPLE_BLOCK, S - s0)
                _predict_block(rho_d, rho_s, c_x, c_y, c_z, n, wi, wo, t, s0, nb, *work)
                for k in range(nb):
                    s = s0 + k
                    up = wi[t, s, 2] > 0 and wo[t, s, 2] > 0
                    for c in range(C):
                        out[t, s, c] = f[c, k] if up else 0.0
    return out


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def squared_residuals_lobes(rho_d, rho_s, c_x, c_y, c_z, n, wi, wo, f_r):
    """Σ_c (:func:`eval_lobes` − ``f_r``)² per sample, ``(T, S)``: the bits of ``sample_squares(eval − f_r)``
    (the same prediction, the channels' squares summed in order) without the ``(T, S, C)`` prediction and
    difference.  Why: the Fit node scores every fit by these squares, and writing, subtracting and reducing those
    arrays took 8.8 of a 1-lobe tile's ms for them against 3.4 here."""
    T, S, _ = wi.shape
    C = rho_d.shape[1]
    out = np.empty((T, S))
    for chunk in prange((T + TEXEL_CHUNK - 1) // TEXEL_CHUNK):
        work = _prediction_scratch(C, S)
        f = work[-1]
        for t in range(chunk * TEXEL_CHUNK, min(T, (chunk + 1) * TEXEL_CHUNK)):
            for s0 in range(0, S, SAMPLE_BLOCK):
                nb = min(SAMPLE_BLOCK, S - s0)
                _predict_block(rho_d, rho_s, c_x, c_y, c_z, n, wi, wo, t, s0, nb, *work)
                for k in range(nb):
                    s = s0 + k
                    up = wi[t, s, 2] > 0 and wo[t, s, 2] > 0
                    d = (f[0, k] if up else 0.0) - f_r[t, s, 0]
                    acc = d * d
                    for c in range(1, C):
                        d = (f[c, k] if up else 0.0) - f_r[t, s, c]
                        acc += d * d
                    out[t, s] = acc
    return out


@njit(cache=True, nogil=True)
def _prediction_scratch(C, S):
    """The working rows of :func:`_predict_block`, made once per task: ω_i ⊙ ω_o's three rows, the lobe's
    x, log x, n log x and value, the exp/log scratch, and the prediction a row per channel (last)."""
    B = max(1, min(SAMPLE_BLOCK, S))  # a block's scratch, no longer than the samples
    return (np.empty(B), np.empty(B), np.empty(B), np.ones(B), np.empty(B), np.empty(B), np.empty(B), np.empty(B),
            np.empty(B, np.int64), np.empty((C, B)))


@njit(cache=True, nogil=True, error_model="numpy")
def _predict_block(rho_d, rho_s, c_x, c_y, c_z, n, wi, wo, t, s0, nb, pxx, pyy, pzz, dot, lx, y, sv, scratch, expo,
                   f):
    """Texel ``t``'s prediction above the horizon over samples ``s0 : s0 + nb``, into ``f`` (a row per channel, so
    its sums run in SIMD lanes): :func:`eval_lobes`' arithmetic, shared with :func:`squared_residuals_lobes`."""
    L, C = rho_s.shape[1], rho_d.shape[1]
    for k in range(nb):
        s = s0 + k
        pxx[k] = wi[t, s, 0] * wo[t, s, 0]
        pyy[k] = wi[t, s, 1] * wo[t, s, 1]
        pzz[k] = wi[t, s, 2] * wo[t, s, 2]
    for c in range(C):
        fc, rd = f[c], rho_d[t, c]
        for k in range(nb):
            fc[k] = rd
    for j in range(L):
        cx, cy, cz, nj = c_x[t, j], c_y[t, j], c_z[t, j], n[t, j]
        for k in range(nb):
            x = cx * pxx[k] + cy * pyy[k] + cz * pzz[k]
            dot[k] = x if x > 0.0 else 1.0
        simd_log(dot, lx, scratch, expo, nb)
        for k in range(nb):
            yk = nj * lx[k]
            y[k] = LOG_CAP if yk > LOG_CAP else yk  # NaN (a NaN exponent) passes, as in NumPy
        simd_exp(y, sv, scratch, expo, nb)
        for k in range(nb):
            sv[k] = sv[k] if cx * pxx[k] + cy * pyy[k] + cz * pzz[k] > 0.0 else 0.0
        for c in range(C):
            fc, rs = f[c], rho_s[t, j, c]
            for k in range(nb):
                fc[k] += rs * sv[k]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lobe_quadrature(a, n, dirs, weights):
    """``Σ_o w_o max(0, a_j·ω_o)^n_j`` per texel and lobe, ``(T, L)``: each lobe seen from one ω_i is a cosine
    lobe about the vector ``a`` (``LafortuneModel.albedo_quadrature``), summed over a quadrature's directions
    ``(N, 3)`` in SIMD lanes (:func:`simd_log`, :func:`simd_exp`); exponents capped at e^LOG_CAP as
    ``positive_power``."""
    T, L = n.shape
    N = dirs.shape[0]
    out = np.zeros((T, L))
    dx, dy, dz = dirs[:, 0].copy(), dirs[:, 1].copy(), dirs[:, 2].copy()
    B = max(1, min(SAMPLE_BLOCK, N))  # a block's scratch, no longer than the directions
    for t in prange(T):
        x_, lx, y, v = np.ones(B), np.zeros(B), np.zeros(B), np.zeros(B)
        scratch, expo = np.zeros(B), np.zeros(B, np.int64)
        dots, zero, rows = np.zeros(B), np.zeros(B), np.zeros((3, B))
        for j in range(L):
            ax, ay, az = a[t, j, 0], a[t, j, 1], a[t, j, 2]
            acc = 0.0
            for s0 in range(0, N, SAMPLE_BLOCK):
                nb = min(SAMPLE_BLOCK, N - s0)
                for k in range(nb):
                    dots[k] = ax * dx[s0 + k] + ay * dy[s0 + k] + az * dz[s0 + k]
                # a·ω_o as a lobe with C_xy = 1 on pxy = a·ω_o, pzz = 0: rows[0] = w_o max(0, a·ω_o)^n
                _lobe(1.0, n[t, j], dots, zero, weights[s0:s0 + nb], nb, x_, lx, y, v, scratch, expo, rows[0],
                           rows[1], rows[2], False)
                part = 0.0
                for k in range(nb):
                    part += rows[0, k]
                acc += part
            out[t, j] = acc
    return out


@njit(cache=True, fastmath={"reassoc", "contract"}, inline="always")
def _dot(a, b, n):
    """``Σ_k a[k] b[k]`` over the first ``n`` entries, in SIMD lanes (``reassoc``: the additions in another order)."""
    acc = 0.0
    for k in range(n):
        acc += a[k] * b[k]
    return acc


@njit(cache=True, fastmath={"reassoc", "contract"}, inline="always")
def _candidate_sums(ev, wl, r, s2, m, second, G, h):
    """A scan candidate's sums with three channels and at most two lobes, in one pass over its ``m`` samples: with
    e its lobe values ``ev`` times the weights ``wl``, ``G[0, 0]`` = Σ e², ``h[0, c]`` = Σ e·r_c and, with a
    ``second`` lobe (weighted values ``s2``), ``G[0, 1]`` = ``G[1, 0]`` = Σ e·s2.  Why: the same sums as separate
    dot products read the candidate's values five times."""
    r0, r1, r2 = r[0], r[1], r[2]
    g00, h0, h1, h2, g01 = 0.0, 0.0, 0.0, 0.0, 0.0
    for k in range(m):
        e = ev[k] * wl[k]
        g00 += e * e
        h0 += e * r0[k]
        h1 += e * r1[k]
        h2 += e * r2[k]
        g01 += e * s2[k]
    G[0, 0] = g00
    h[0, 0], h[0, 1], h[0, 2] = h0, h1, h2
    if second:
        G[0, 1] = G[1, 0] = g01


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def scan_first_exponent(x, log_exponents, wi, wo, f, w, lobes, aniso, has_beta):
    """Starting point: for each texel, the lobe-1 exponent from ``log_exponents`` with the smallest cost.

    For every candidate the lobe magnitudes are solved by least squares (ρ_d
    and the other lobes' shapes held at ``x``), clipped to ≥ 0, and the cost
    follows in closed form from the same sums.  What does not depend on the
    candidate (log(C·ω) of every lobe, the other lobes' values, the diffuse
    residuals and their sums) is taken once per texel, so a candidate costs one
    exp per sample.  The logs and exps run in SIMD lanes (:func:`simd_log`,
    :func:`simd_exp`) over the texel's lit samples, and so do a candidate's sums
    (:func:`_dot`; summed sample by sample they were a chain of dependent adds,
    22.8 → 19.1 ms CPU for a 1024-texel tile at 2 lobes, 15.5 → 13.8 at 1, with
    the same output to the bit on benchmarks/fit.py's tile), the small systems are
    solved in place (:func:`_solve`), and the working arrays are made once per
    task: the scalar libm calls, LAPACK calls and allocations per texel were
    most of the scan's time (an eighth of a Fit tile).  With three channels and
    1-2 lobes a candidate's sums take one pass (:func:`_candidate_sums`).
    Returns the updated fit-form rows.
    """
    T, K = x.shape
    S = wi.shape[1]
    C = f.shape[2]
    out = x.copy()
    kn1 = C + C + 1 + aniso  # index of log_exponent_1
    L = max(lobes, 1)
    for chunk in prange((T + TEXEL_CHUNK - 1) // TEXEL_CHUNK):
        cx, cy, n, rho0 = np.empty(L), np.empty(L), np.empty(L), np.empty((L, C))
        dots = np.ones((L, S))  # per lobe, C·ω of each lit sample (1 where it is dark: log 0, masked below)
        lit = np.zeros((L, S), np.bool_)
        log_dot, sv, wl = np.empty(S), np.zeros((L, S)), np.empty(S)
        wt, r = np.empty(S), np.empty((C, S))  # the weighted diffuse residuals, a row per channel
        y, ev, scratch, expo = np.empty(S), np.empty(S), np.empty(S), np.empty(S, np.int64)
        G1, h1 = np.zeros((L, L)), np.zeros((L, C))  # the candidate-free part of G (lobes 2.. among themselves)
        G, h, M, b, rho = np.empty((L, L)), np.empty((L, C)), np.empty((L, L)), np.empty(L), np.empty((L, C))
        for t in range(chunk * TEXEL_CHUNK, min(T, (chunk + 1) * TEXEL_CHUNK)):
            best = np.inf
            cb, sb = _unpack(x, t, lobes, aniso, has_beta, C, rho0, cx, cy, n)
            # Per sample, once: C·ω of every lobe, the weight and the weighted diffuse residuals; samples that add
            # nothing to the lobe sums are left out.
            e0 = 0.0
            m = 0
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
                    lit[j, m] = dot > 0.0
                    dots[j, m] = dot if dot > 0.0 else 1.0
                wt[m] = ws
                for c in range(C):
                    r0 = (f[t, s, c] - x[t, c]) * ws
                    r[c, m] = r0
                    e0 += r0 * r0
                m += 1
            if lobes:
                simd_log(dots[0], log_dot, scratch, expo, m)
                for k in range(m):  # the weight where lobe 1 lights the sample
                    wl[k] = wt[k] if lit[0, k] else 0.0
            for j in range(1, lobes):  # the other lobes' values, weighted
                sj = sv[j]
                simd_log(dots[j], y, scratch, expo, m)
                for k in range(m):
                    yk = n[j] * y[k]
                    y[k] = yk if yk < LOG_CAP else LOG_CAP
                simd_exp(y, sj, scratch, expo, m)
                for k in range(m):
                    sj[k] = sj[k] * wt[k] if lit[j, k] else 0.0
            for j in range(1, lobes):
                for c in range(C):
                    h1[j, c] = _dot(sv[j], r[c], m)
                for i in range(1, lobes):
                    G1[j, i] = _dot(sv[j], sv[i], m)
            for q in range(log_exponents.size):
                n0 = math.exp(log_exponents[q])
                G[:] = G1
                h[:] = h1
                for k in range(m):  # the candidate's lobe at every sample, its exps and sums in SIMD lanes
                    yk = n0 * log_dot[k]
                    y[k] = yk if yk < LOG_CAP else LOG_CAP
                simd_exp(y, ev, scratch, expo, m)
                if C == 3 and lobes <= 2:  # the usual fit: its sums in one pass
                    _candidate_sums(ev, wl, r, sv[lobes - 1], m, lobes == 2, G, h)
                else:
                    for k in range(m):
                        ev[k] = ev[k] * wl[k]
                    G[0, 0] = _dot(ev, ev, m)
                    for c in range(C):
                        h[0, c] = _dot(ev, r[c], m)
                    for i in range(1, lobes):
                        G[0, i] = G[i, 0] = _dot(ev, sv[i], m)
                for j in range(lobes):
                    G[j, j] += 1e-12
                for c in range(C):  # the magnitudes of each channel: G ρ = h, in place
                    M[:] = G
                    for j in range(lobes):
                        b[j] = h[j, c]
                    ok = _solve(M, b, lobes)
                    for j in range(lobes):
                        v = b[j] if ok else 0.0
                        rho[j, c] = min(max(v, 0.0), 1e6) if np.isfinite(v) else 0.0
                cost = e0
                for c in range(C):
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


@njit(parallel=True, cache=True, nogil=True)
def prepare_isotropic(wi, wo, w, f):
    """What :func:`normal_equations_isotropic` and :func:`cost_isotropic` read, in one pass over the samples:
    ``(ω_i,xy·ω_o,xy, ω_i,z·ω_o,z, the weight where the sample is lit (0 elsewhere), f_r channel-major (T, C, S),
    each texel's weighted energy of the unlit samples, and of all samples)`` (:func:`_prepare_texel`).  Why
    compiled: the same steps in NumPy were six passes over ``(T, S, 3)`` arrays and a transposing copy, a tenth
    of a Fit tile (py-spy)."""
    T, S, C = f.shape
    pxy, pzz, w_lit = np.empty((T, S)), np.empty((T, S)), np.empty((T, S))
    f_t = np.empty((T, C, S))
    e_unlit, energy = np.zeros(T), np.zeros(T)
    for t in prange(T):
        e_unlit[t], energy[t], _ = _prepare_texel(wi, wo, w, f, t, pxy, pzz, w_lit, f_t, t)
    return pxy, pzz, w_lit, f_t, e_unlit, energy


@njit(cache=True, nogil=True)
def _prepare_texel(wi, wo, w, f, t, pxy, pzz, w_lit, f_t, d):
    """Texel ``t``'s samples prepared into row ``d`` of ``pxy``, ``pzz``, ``w_lit``, ``f_t`` (as
    :func:`prepare_isotropic` describes them); returns ``(unlit energy, energy, any sample weighted)``.  Below
    the horizon the model is 0, so an unlit sample's residual is −f_r·w whatever the parameters."""
    S, C = f.shape[1], f.shape[2]
    eu, ea = 0.0, 0.0
    weighted = False
    for s in range(S):
        ws = w[t, s]
        iz, oz = wi[t, s, 2], wo[t, s, 2]
        pxy[d, s] = wi[t, s, 0] * wo[t, s, 0] + wi[t, s, 1] * wo[t, s, 1]
        pzz[d, s] = iz * oz
        lit = ws != 0.0 and iz > 0.0 and oz > 0.0
        w_lit[d, s] = ws if lit else 0.0
        weighted = weighted or ws > 0.0
        for c in range(C):
            fc = f[t, s, c]
            f_t[d, c, s] = fc
            r = fc * ws
            ea += r * r
            if not lit:
                eu += r * r
    return eu, ea, weighted


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
        self._isotropic: list | None = None  # normal_equations_isotropic's inputs, prepared on first use
        self._energy: np.ndarray | None = None

    def _prepared(self):
        """What :func:`normal_equations_isotropic` reads, once per problem (LM calls it every iteration), made by
        :func:`prepare_isotropic`; the data energy comes with it."""
        if self._isotropic is None:
            *self._isotropic, self._energy = run_parallel(prepare_isotropic, self.wi, self.wo, self.weight, self.f_r)
        return self._isotropic

    def data_energy(self):
        if self._energy is None:
            wf = self.f_r * self.weight[..., None]
            self._energy = np.einsum("tsc,tsc->t", wf, wf)
        return self._energy

    def normal_equations(self, x, idx):
        x, idx = np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(idx, dtype=np.int64)
        lobes, aniso, has_beta = self.flags
        if not aniso and not has_beta:
            return run_parallel(normal_equations_isotropic, x, idx, *self._prepared(), lobes)
        return run_parallel(normal_equations, x, idx, self.wi, self.wo, self.f_r, self.weight, *self.flags)

    def levenberg_marquardt(self, x0, bounds, *, iterations, tolerance, damping, free, limits, exact, max_damping,
                            max_step=None):
        """The whole LM solve compiled (:func:`lm_isotropic`) for isotropic lobes without β; None otherwise (the
        caller runs the NumPy iteration).  ``bounds`` must be the form's; ``limits`` None: no projection;
        ``max_step`` None: steps of any length."""
        lobes, aniso, has_beta = self.flags
        args = None if aniso or has_beta else self.form.packed_limits(limits, x0.shape[0])
        if args is None:
            return None
        lo, hi, peak, has_peak, n_cap, growth, s2, c2, n_lo, n_hi, rho_at, c_at, ln_at = args
        if not (np.array_equal(bounds[0], lo) and np.array_equal(bounds[1], hi)):
            return None
        return run_parallel(lm_isotropic, np.ascontiguousarray(x0, np.float64), self.wi, self.wo, self.weight,
                            self.f_r, lobes, lo, hi,
                            np.asarray(free, np.bool_), limits is not None, peak, has_peak, n_cap, growth, s2, c2,
                            n_lo, n_hi, rho_at, c_at, ln_at, int(iterations), float(tolerance), float(damping),
                            float(max_damping), float(exact),
                            np.full(x0.shape[1], np.inf) if max_step is None else np.asarray(max_step, np.float64))

    def cost(self, x, idx):
        x, idx = np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(idx, dtype=np.int64)
        lobes, aniso, has_beta = self.flags
        if not aniso and not has_beta:
            return run_parallel(cost_isotropic, x, idx, *self._prepared(), lobes)
        return self.normal_equations(x, idx)[2]


# -- variable projection: only the lobe shapes iterate, magnitudes are solved in closed form ---------------

#: The separable start's lobe-1 exponents: n = 2, 4, ..., 2^10 (the text's n = 10 among them, roughly), each
#: the square of the last, so a scan costs one log and a multiply per candidate.
SCAN_DOUBLINGS = 10
#: Shapes tried for lobe 2 after lobe 1's scan, and for a lobe the iteration left weak: (C_xy, doublings), i.e.
#: n = 2 .. 2^doublings: back-scatter (the text's C = (1, 1, 1)) or a second forward lobe.
RESEED = ((1.0, 5), (-1.0, 7))
#: Longest LM step in C_xy and in log n.
MAX_STEP = (0.25, 1.0)
#: A lobe whose largest magnitude is at most this fraction of the strongest lobe's is re-seeded (kept if better):
#: 0, only a dead lobe (one with a magnitude keeps its own gradient).
WEAK_LOBE = 0.0
#: Two lobes closer than this in C_xy and in log n (and on the same side) are twins: the weaker is re-seeded.
TWIN = (0.2, 1.0)


@njit(cache=True, inline="always")
def _solve(A, b, n):
    """Solve the leading ``n × n`` block of ``A`` against ``b`` in place (Gaussian elimination, partial
    pivoting; ``A`` and ``b`` are overwritten, ``b`` holds the solution).  Returns False if singular."""
    for k in range(n):
        p = k
        big = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > big:
                big, p = abs(A[i, k]), i
        if not big > 0.0:
            return False
        if p != k:
            for j in range(n):
                A[k, j], A[p, j] = A[p, j], A[k, j]
            b[k], b[p] = b[p], b[k]
        for i in range(k + 1, n):
            m = A[i, k] / A[k, k]
            for j in range(k, n):
                A[i, j] -= m * A[k, j]
            b[i] -= m * b[k]
    for k in range(n - 1, -1, -1):
        acc = b[k]
        for j in range(k + 1, n):
            acc -= A[k, j] * b[j]
        b[k] = acc / A[k, k]
    return True


@njit(cache=True, nogil=True)
def _nnls(G, h, sel, L1, a, free, A, rhs):
    """min over a ≥ 0 of aᵀGa − 2aᵀh on the basis rows ``sel[:L1]`` of ``G``, ``h`` (one channel).

    With at most 4 unknowns the exact solution is the best feasible one among
    the unconstrained solutions on every subset (the KKT point is one of
    them); the full set comes first, and when its solution is feasible it is
    the optimum and nothing else is tried.  Writes ``a`` and the mask
    ``free``; returns the objective.
    """
    best = 0.0
    for i in range(L1):
        a[i] = 0.0
        free[i] = False
    idx = np.empty(L1, np.int64)
    full = (1 << L1) - 1
    for m in range(full, 0, -1):  # all unknowns free first: feasible there (the usual case) is the optimum
        mask = m
        n = 0
        for i in range(L1):
            if mask >> i & 1:
                idx[n] = i
                n += 1
        for i in range(n):
            rhs[i] = h[sel[idx[i]]]
            for j in range(n):
                A[i, j] = G[sel[idx[i]], sel[idx[j]]]
            A[i, i] += 1e-12 * (1.0 + A[i, i])
        if not _solve(A, rhs, n):
            continue
        ok = True
        for i in range(n):
            if not (rhs[i] >= 0.0):
                ok = False
        if not ok:
            continue
        val = 0.0  # at the subset's optimum, aᵀGa − 2aᵀh = −aᵀh
        for i in range(n):
            val -= rhs[i] * h[sel[idx[i]]]
        if val < best:
            best = val
            for i in range(L1):
                a[i] = 0.0
                free[i] = False
            for i in range(n):
                a[idx[i]] = rhs[i]
                free[idx[i]] = True
        if mask == full:
            break
    return best


@njit(cache=True, inline="always")
def _accumulate(G, H, b, m, w2, f, d, s):
    """One sample's share of a Gram system: the upper triangle of ``G += w² b bᵀ`` and ``H += w² b f[d, s]ᵀ``
    over the first ``m`` basis values."""
    for i in range(m):
        bi = b[i] * w2
        for k in range(i, m):
            G[i, k] += bi * b[k]
        for k in range(H.shape[1]):
            H[i, k] += bi * f[d, s, k]


@njit(cache=True, nogil=True, error_model="numpy")
def _gram(pxy, pz, ws, S, lobes, c, n, f, d, G, H, derivatives):
    """One pass over a texel's samples: ``G = Σ w² b bᵀ``, ``H = Σ w² b fᵀ`` for the basis
    ``b = [1, s_1..s_L, (∂s_j/∂c_j, ∂s_j/∂log n_j) per lobe]`` (the derivatives only if asked; else those rows are 0).

    ``s = exp(n log x)`` reuses ``log x`` for ∂s/∂log n = n s log x and ∂s/∂c = n s pxy / x: one log and
    one exp per sample and lobe, no pow.  In blocks of :data:`SAMPLE_BLOCK` samples, row by row, in SIMD lanes
    as :func:`normal_equations_isotropic` (``error_model="numpy"``: no zero-division branch in the loops).
    """
    m = G.shape[0]
    C = H.shape[1]
    G[:] = 0.0
    H[:] = 0.0
    B = max(1, min(SAMPLE_BLOCK, S))  # a block's scratch (made per call), no longer than the samples
    Bw, Fw = np.zeros((m, B)), np.zeros((C, B))  # b·w and f·w, a row each
    x_, lx, y, v = np.ones(B), np.zeros(B), np.zeros(B), np.zeros(B)
    scratch, expo = np.zeros(B), np.zeros(B, np.int64)
    for s0 in range(0, S, SAMPLE_BLOCK):
        nb = min(SAMPLE_BLOCK, S - s0)
        P, Z, W = pxy[s0:s0 + nb], pz[s0:s0 + nb], ws[s0:s0 + nb]
        b0 = Bw[0]
        for k in range(nb):
            b0[k] = W[k]
        for ch in range(C):
            fc = Fw[ch]
            for k in range(nb):
                fc[k] = f[d, s0 + k, ch] * W[k]
        for j in range(lobes):
            q = 1 + lobes + 2 * j
            _lobe(c[j], n[j], P, Z, W, nb, x_, lx, y, v, scratch, expo, Bw[1 + j], Bw[q], Bw[q + 1], derivatives)
        _gram_block(Bw, Fw, nb, G, H)
    for i in range(m):
        for k in range(i):
            G[i, k] = G[k, i]


@njit(cache=True, inline="always")
def _magnitudes(G, H, L1, sel, a, free, A, rhs, col, acol, fcol):
    """Non-negative magnitudes per channel (``a`` (L1, C)) for the current basis; returns Σ_c objective."""
    C = H.shape[1]
    total = 0.0
    for k in range(C):
        for i in range(G.shape[0]):
            col[i] = H[i, k]
        total += _nnls(G, col, sel, L1, acol, fcol, A, rhs)
        for i in range(L1):
            a[i, k] = acol[i]
            free[i, k] = fcol[i]
    return total


@njit(cache=True, nogil=True)
def _box(theta, lobes, c_lo, c_hi, ln_lo, ln_hi, growth, s2, c2):
    """Clip lobe shapes to their box; with a grazing-growth bound, |c| ≤ max((g^(1/n) − cos²θ)/sin²θ, 1)."""
    for j in range(lobes):
        ln = min(max(theta[2 * j + 1], ln_lo), ln_hi)
        theta[2 * j + 1] = ln
        lo, hi = c_lo, c_hi
        if growth > 0.0:
            cap = max((math.exp(min(math.log(growth) / math.exp(ln), 50.0)) - c2) / s2, 1.0)
            lo, hi = max(lo, -cap), min(hi, cap)
        theta[2 * j] = min(max(theta[2 * j], lo), hi)


@njit(cache=True, nogil=True)
def _scan(jq, cand_c, cand_k, theta, pxy, pz, ws, S, L, f, t, ln_lo, ln_hi):
    """Lobe ``jq``'s best shape among candidates, the other lobes held, magnitudes by NNLS; writes theta.

    Candidates come in groups (C_xy = ``cand_c[g]``, n = 2, 4, ..., 2^``cand_k[g]``): one log per group and
    sample, then each n by squaring the last.  One pass over the samples accumulates, per candidate, only
    the sums its own NNLS needs (with 1, the held lobes, itself, the data), not a Gram of all candidates.
    """
    C = f.shape[2]
    Q = 0
    for g in range(cand_c.size):
        Q += cand_k[g]
    L1 = L + 1
    base = np.zeros((L, L))  # Gram of [1, held lobes]
    hb = np.zeros((L, C))
    gq = np.zeros((Q, L1))  # Σ w² s_q · [1, held..., s_q]
    hq = np.zeros((Q, C))
    b = np.empty(L)
    b[0] = 1.0
    v = np.empty(Q)
    for s in range(S):
        wt = ws[s]
        if wt == 0.0:
            continue
        k = 1
        for j in range(L):
            if j == jq:
                continue
            x = theta[2 * j] * pxy[s] + pz[s]
            b[k] = math.exp(min(math.exp(theta[2 * j + 1]) * math.log(x), LOG_CAP)) if x > 0.0 else 0.0
            k += 1
        q = 0
        for g in range(cand_c.size):
            x = max(cand_c[g] * pxy[s] + pz[s], 0.0)
            for _ in range(cand_k[g]):
                x = min(x * x, 1e100)
                v[q] = x
                q += 1
        w2 = wt * wt
        _accumulate(base, hb, b, L, w2, f, t, s)
        for q in range(Q):
            vq = v[q] * w2
            for i in range(L):
                gq[q, i] += vq * b[i]
            gq[q, L] += vq * v[q]
            for k2 in range(C):
                hq[q, k2] += vq * f[t, s, k2]
    sel = np.arange(L1)
    A, rhs, col = np.empty((L1, L1)), np.empty(L1), np.empty(L1)
    acol, fcol = np.empty(L1), np.empty(L1, np.bool_)
    a, free = np.empty((L1, C)), np.empty((L1, C), np.bool_)
    Gs, Hs = np.empty((L1, L1)), np.empty((L1, C))
    best, pick_c, pick_ln = np.inf, 0.0, 0.0
    q = 0
    for g in range(cand_c.size):
        for kk in range(1, cand_k[g] + 1):
            ln = kk * math.log(2.0)
            if ln_lo <= ln <= ln_hi:
                for i in range(L):
                    for k2 in range(L):
                        Gs[i, k2] = base[i, k2] if k2 >= i else base[k2, i]
                    Gs[i, L] = gq[q, i]
                    Gs[L, i] = gq[q, i]
                    for k2 in range(C):
                        Hs[i, k2] = hb[i, k2]
                Gs[L, L] = gq[q, L]
                for k2 in range(C):
                    Hs[L, k2] = hq[q, k2]
                val = _magnitudes(Gs, Hs, L1, sel, a, free, A, rhs, col, acol, fcol)
                if val < best:
                    best, pick_c, pick_ln = val, cand_c[g], ln
            q += 1
    if best < np.inf:
        theta[2 * jq] = pick_c
        theta[2 * jq + 1] = pick_ln
    return best


@njit(cache=True, nogil=True)
def _kaufman(G, H, a, free, L, JJ, g, DB, Y, y):
    """Kaufman's JᵀJ = Σ_c DᵀD − DᵀB (BᵀB)⁻¹ BᵀD (over the channel's free magnitudes) and the gradient Dᵀr,
    all from the Gram sums."""
    P, L1, C = 2 * L, L + 1, H.shape[1]
    for k in range(P):
        g[k] = 0.0
        for l in range(P):
            JJ[k, l] = 0.0
    for ch in range(C):
        for k in range(P):
            ak = a[1 + k // 2, ch]
            ik = 1 + L + k
            acc = -H[ik, ch]
            for i in range(L1):
                acc += G[ik, i] * a[i, ch]
            g[k] += ak * acc
            for l in range(P):
                JJ[k, l] += ak * a[1 + l // 2, ch] * G[ik, 1 + L + l]
            for i in range(L1):
                DB[k, i] = ak * G[ik, i] if free[i, ch] else 0.0
        for l in range(P):
            nf = 0
            for i in range(L1):
                if free[i, ch]:
                    y[nf] = DB[l, i]
                    r2 = 0
                    for i2 in range(L1):
                        if free[i2, ch]:
                            Y[nf, r2] = G[i, i2]
                            r2 += 1
                    nf += 1
            for i in range(nf):
                Y[i, i] += 1e-12 * (1.0 + Y[i, i])
            if nf == 0 or not _solve(Y, y, nf):
                continue
            for k in range(P):
                acc = 0.0
                r2 = 0
                for i in range(L1):
                    if free[i, ch]:
                        acc += DB[k, i] * y[r2]
                        r2 += 1
                JJ[k, l] -= acc


@njit(parallel=True, cache=True, nogil=True)
def separable_lm(wi, wo, f, w, theta0, ln_hi, c_lo, c_hi, ln_lo, growth, s2, c2, scan, iterations, tolerance,
                 damping, max_damping, exact):
    """Levenberg–Marquardt over the lobe shapes alone (c_j, log n_j), magnitudes by non-negative least squares.

    Variable projection (Golub–Pereyra, Kaufman's Jacobian): for fixed shapes
    the model is linear in ρ_d and ρ_s,j per channel, so those are solved in
    closed form on every evaluation and the iteration has 2L unknowns instead
    of 3 + L(3 + 2).  Every quantity comes from the Gram sums of one pass
    (:func:`_gram`): the cost aᵀGa − 2aᵀh + Σw²f², the gradient Dᵀr and
    Kaufman's JᵀJ (:func:`_kaufman`).  ``scan``: first pick lobe 1's exponent
    from :data:`SCAN_DOUBLINGS`, then lobe 2's shape from :data:`RESEED`, one
    pass each.  A lobe the iteration leaves with no magnitude in any channel
    has no gradient and would stay dead, and two lobes with nearly one shape
    (:data:`TWIN`) fit one feature twice: such a lobe is re-seeded once from
    :data:`RESEED` and the iteration continues; the texel keeps the better of
    the two results.  A single lobe is re-seeded when the best candidate
    already beats its converged fit (another basin: a back-scattering texel
    started forward, or a spike on one bright sample).  Each texel iterates until its
    own convergence.  Returns ``theta (T, 2L)``, magnitudes ``(T, L + 1, C)``,
    ``cost (T,)``, ``converged (T,)`` and iterations used ``(T,)``.
    """
    T, S, _ = wi.shape
    C = f.shape[2]
    L = theta0.shape[1] // 2
    L1, P = L + 1, 2 * L
    m = 1 + L + P
    re_c = np.array([r[0] for r in RESEED])
    re_k = np.array([r[1] for r in RESEED])
    one_k = np.array([SCAN_DOUBLINGS])
    max_step = np.array(MAX_STEP)
    theta_out = np.empty((T, P))
    mags = np.zeros((T, L1, C))
    cost_out = np.zeros(T)
    conv_out = np.zeros(T, np.bool_)
    iters = np.zeros(T, np.int64)
    for t in prange(T):
        pxy, pz, ws = np.empty(S), np.empty(S), np.empty(S)
        energy = 0.0
        for s in range(S):
            wt = w[t, s]
            pxy[s] = wi[t, s, 0] * wo[t, s, 0] + wi[t, s, 1] * wo[t, s, 1]
            pz[s] = wi[t, s, 2] * wo[t, s, 2]
            for k in range(C):
                energy += (f[t, s, k] * wt) ** 2
            ws[s] = wt if (wi[t, s, 2] > 0.0 and wo[t, s, 2] > 0.0) else 0.0
        theta = theta0[t].copy()
        _box(theta, L, c_lo, c_hi, ln_lo, ln_hi[t], growth, s2, c2)
        if scan and L > 0:
            _scan(0, theta[:1].copy(), one_k, theta, pxy, pz, ws, S, L, f, t, ln_lo, ln_hi[t])
            if L > 1:
                _scan(1, re_c, re_k, theta, pxy, pz, ws, S, L, f, t, ln_lo, ln_hi[t])
            _box(theta, L, c_lo, c_hi, ln_lo, ln_hi[t], growth, s2, c2)
        sel = np.arange(L1)
        A, rhs, col = np.empty((L1, L1)), np.empty(L1), np.empty(m)
        acol, fcol = np.empty(L1), np.empty(L1, np.bool_)
        a, free = np.zeros((L1, C)), np.zeros((L1, C), np.bool_)
        a2, free2 = np.empty((L1, C)), np.empty((L1, C), np.bool_)
        G, H = np.zeros((m, m)), np.zeros((m, C))
        G2, H2 = np.empty((m, m)), np.empty((m, C))
        JJ, g, M, step = np.empty((P, P)), np.empty(P), np.empty((P, P)), np.empty(P)
        DB, Y, y = np.empty((P, L1)), np.empty((L1, L1)), np.empty(L1)
        c, n, trial = np.empty(L), np.empty(L), np.empty(P)
        frozen = np.zeros(P, np.bool_)
        used = 0
        done = False
        saved_theta, saved_a, saved_cost, saved_done = theta.copy(), a.copy(), np.inf, False
        for rnd in range(2):
            for j in range(L):
                c[j], n[j] = theta[2 * j], math.exp(theta[2 * j + 1])
            _gram(pxy, pz, ws, S, L, c, n, f, t, G, H, True)
            cost = energy + _magnitudes(G, H, L1, sel, a, free, A, rhs, col, acol, fcol)
            lam = damping
            done = not (energy > 0.0) or L == 0 or cost <= exact * energy
            budget = used + iterations
            while not done and used < budget:
                used += 1
                _kaufman(G, H, a, free, L, JJ, g, DB, Y, y)
                # A shape parameter held at its bound by a gradient pointing out of the box is frozen for this
                # step (and the others solved without it): clipping an unconstrained step instead would leave
                # the others moved for a direction that was not taken, and the texel stuck at its start.
                for k in range(P):
                    frozen[k] = False
                ok = True
                for _attempt in range(2):
                    for k in range(P):
                        step[k] = 0.0 if frozen[k] else -g[k]
                        dk = max(JJ[k, k], 1e-12)
                        for l in range(P):
                            M[k, l] = 0.0 if (frozen[k] or frozen[l]) else JJ[k, l]
                        M[k, k] = 1.0 if frozen[k] else M[k, k] + lam * dk
                    ok = _solve(M, step, P)
                    if not ok:
                        break
                    # A step longer than MAX_STEP (in C_xy, log n) is shortened: a weak lobe has little
                    # curvature and would otherwise jump into another lobe's role, leaving its own dead.
                    shrink = 1.0
                    for k in range(P):
                        if not np.isfinite(step[k]):
                            step[k] = 0.0
                        shrink = min(shrink, max_step[k % 2] / max(abs(step[k]), 1e-300))
                    for k in range(P):
                        trial[k] = theta[k] + shrink * step[k]
                    _box(trial, L, c_lo, c_hi, ln_lo, ln_hi[t], growth, s2, c2)
                    again = False
                    for k in range(P):
                        if not frozen[k] and trial[k] == theta[k] and step[k] != 0.0:
                            frozen[k] = True
                            again = True
                    if not again:
                        break
                if not ok:
                    lam *= 4.0
                    done = lam > max_damping
                    continue
                big, scale = 0.0, 1e-12
                # The quadratic model's predicted decrease, −2gᵀδ − δᵀJᵀJδ: when even that is below the
                # tolerance, the step is not worth a pass over the samples (converged at an undamped step).
                pred = 0.0
                for k in range(P):
                    dk = trial[k] - theta[k]
                    pred -= 2.0 * g[k] * dk
                    for l in range(P):
                        pred -= dk * JJ[k, l] * (trial[l] - theta[l])
                if lam <= damping and pred < tolerance * cost:
                    done = True
                    break
                for k in range(P):
                    big = max(big, abs(trial[k] - theta[k]))
                    scale = max(scale, abs(theta[k]))
                for j in range(L):
                    c[j], n[j] = trial[2 * j], math.exp(trial[2 * j + 1])
                _gram(pxy, pz, ws, S, L, c, n, f, t, G2, H2, True)
                new = energy + _magnitudes(G2, H2, L1, sel, a2, free2, A, rhs, col, acol, fcol)
                if np.isfinite(new) and new < cost:
                    gain = (cost - new) / max(cost, 1e-300)
                    theta[:] = trial
                    G[:, :] = G2
                    H[:, :] = H2
                    a[:, :] = a2
                    free[:, :] = free2
                    cost = new
                    lam = max(lam / 3.0, 1e-12)
                    done = gain < tolerance
                else:
                    lam *= 4.0
                    done = big <= 1e-9 * scale or lam > max_damping
                if cost <= exact * energy:
                    done = True
            if rnd == 1:
                if cost > saved_cost:  # the re-seeded lobe did not help: keep the first result
                    theta[:] = saved_theta
                    a[:, :] = saved_a
                    cost, done = saved_cost, saved_done
                break
            if not done:
                break
            cand = theta.copy()
            if L == 1:
                # one lobe: the best re-seed candidate, if it already beats the converged fit, is another
                # basin (a forward start on a back-scattering texel, a spike on one bright sample)
                val = _scan(0, re_c, re_k, cand, pxy, pz, ws, S, L, f, t, ln_lo, ln_hi[t])
                if not energy + val < cost * (1.0 - 1e-9):
                    break
            else:
                weak, lowest, strongest = -1, np.inf, 0.0
                for j in range(L):
                    peak = 0.0
                    for k in range(C):
                        peak = max(peak, a[1 + j, k])
                    strongest = max(strongest, peak)
                    if peak < lowest:
                        weak, lowest = j, peak
                # two lobes doing one lobe's job (same side, nearly the same shape) leave a basin unused
                twins = L == 2 and theta[0] * theta[2] > 0.0 and abs(theta[0] - theta[2]) < TWIN[0] and \
                    abs(theta[1] - theta[3]) < TWIN[1]
                if not (lowest <= WEAK_LOBE * strongest or twins):
                    break
                _scan(weak, re_c, re_k, cand, pxy, pz, ws, S, L, f, t, ln_lo, ln_hi[t])
            saved_theta, saved_a, saved_cost, saved_done = theta.copy(), a.copy(), cost, done
            theta[:] = cand
            _box(theta, L, c_lo, c_hi, ln_lo, ln_hi[t], growth, s2, c2)
        theta_out[t] = theta
        mags[t] = a
        cost_out[t] = max(cost, 0.0)
        conv_out[t] = done
        iters[t] = used
    return theta_out, mags, cost_out, conv_out, iters
