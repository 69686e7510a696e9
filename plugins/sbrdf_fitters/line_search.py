"""McAllister's single-lobe line search (seed 000 §4.3.2), vectorised over texels.

For a trial exponent n the lobe equation ⁿ√f̄_s = C_x ω_i,x ω_r,x + C_y ω_i,y ω_r,y
+ C_z ω_i,z ω_r,z (Eq 4.8) is linear in C and solved by least squares (Eq 4.9);
Brent's method searches log n for the smallest residual.  The design matrix
does not depend on n, so its normal matrix is factorised once per texel and
each trial costs one batched matrix-vector product.

Decisions the text leaves open (notes §8.4), recorded here:
- samples with f̄_s ≤ 0 (about 10% with a 10th-percentile ρ_d) have no real
  n-th root: they are dropped;
- so are, by default, samples below 1% of the texel's peak residual
  (``root_floor``): under any noise their n-th root is near 1 whatever the
  lobe, and fitting them as written drives n to the bracket's low end (the
  "lobes much too broad" failure the text reports).  Measured on 1-lobe data
  with n 5..200: as written, n/n_true ≈ 0.02 already at σ = 10⁻⁸ sr⁻¹; with
  the floor n is right at σ = 10⁻⁴ and too broad at 10⁻², as the text says;
- the isotropic tie C_x = C_y uses the column ω_i,x ω_r,x + ω_i,y ω_r,y;
- the bracket is log n ∈ [log 0.5, log 2000];
- ``objective: root`` measures the residual in root space as written (the
  faithful mode, with its documented bias towards broad lobes under noise);
  ``objective: brdf`` measures it in BRDF space after solving C.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.brdf import positive_power

GOLDEN = 0.3819660112501051


def brent_minimize(objective, a: np.ndarray, b: np.ndarray, iterations: int = 40, tol: float = 1e-5):
    """Brent's minimiser (parabolic steps, golden-section fallback) for many 1-D problems at once.

    ``objective(x)`` maps ``(T,)`` trial points to ``(T,)`` values; each texel
    has its own bracket ``[a, b]``.  Returns ``(x_min, f_min)``.
    """
    a, b = a.astype(float).copy(), b.astype(float).copy()
    x = w = v = a + GOLDEN * (b - a)
    fx = objective(x)
    fw, fv = fx.copy(), fx.copy()
    d = np.zeros_like(x)
    e = np.zeros_like(x)
    for _ in range(iterations):
        m = 0.5 * (a + b)
        tol1 = tol * np.abs(x) + 1e-10
        tol2 = 2 * tol1
        if np.all(np.abs(x - m) <= tol2 - 0.5 * (b - a)):
            break
        # parabola through (v, fv), (w, fw), (x, fx)
        r = (x - w) * (fx - fv)
        q = (x - v) * (fx - fw)
        p = (x - v) * q - (x - w) * r
        q = 2 * (q - r)
        p = np.where(q > 0, -p, p)
        q = np.abs(q)
        with np.errstate(all="ignore"):
            para = p / q
        use_para = (np.abs(e) > tol1) & (np.abs(p) < np.abs(0.5 * q * e)) & (p > q * (a - x)) & (p < q * (b - x))
        golden_e = np.where(x >= m, a - x, b - x)
        e_new = np.where(use_para, d, golden_e)
        d = np.where(use_para, para, GOLDEN * golden_e)
        u_para = x + d
        too_close = use_para & (((u_para - a) < tol2) | ((b - u_para) < tol2))
        d = np.where(too_close, np.where(x < m, tol1, -tol1), d)
        e = e_new
        u = x + np.where(np.abs(d) >= tol1, d, np.where(d > 0, tol1, -tol1))
        fu = objective(u)
        le = fu <= fx
        # shrink the bracket
        a = np.where(le, np.where(u >= x, x, a), np.where(u < x, u, a))
        b = np.where(le, np.where(u >= x, b, x), np.where(u < x, b, u))
        # update v, w, x
        upd_w = ~le & ((fu <= fw) | (w == x))
        upd_v = ~le & ~upd_w & ((fu <= fv) | (v == x) | (v == w))
        v, fv = np.where(le | upd_w, w, np.where(upd_v, u, v)), np.where(le | upd_w, fw, np.where(upd_v, fu, fv))
        w, fw = np.where(le, x, np.where(upd_w, u, w)), np.where(le, fx, np.where(upd_w, fu, fw))
        x, fx = np.where(le, u, x), np.where(le, fu, fx)
    return x, fx


def line_search_lobe(lum_s: np.ndarray, use: np.ndarray, pxx, pyy, pzz, *, anisotropic: bool, objective: str = "root",
                     bracket=(0.5, 2000.0), iterations: int = 40):
    """One lobe ``(C, n)`` per texel from luminance residuals ``lum_s`` (T, S) at samples ``use``.

    Returns ``(c (T, 3) as C_x, C_y, C_z; exponent (T,); cost (T,))``.
    """
    cols = [pxx, pyy, pzz] if anisotropic else [pxx + pyy, pzz]
    A = np.stack(cols, axis=-1) * use[..., None]  # (T, S, k)
    k = A.shape[-1]
    AtA = A.transpose(0, 2, 1) @ A + 1e-12 * np.eye(k)
    AtA_inv = np.linalg.inv(AtA)  # factorised once: independent of n
    log_f = np.log(np.where(use & (lum_s > 0), lum_s, 1.0))

    def solve(log_n):
        root = np.where(use, np.exp(log_f / np.exp(log_n)[:, None]), 0.0)  # ⁿ√f̄_s
        c = (AtA_inv @ (A.transpose(0, 2, 1) @ root[..., None]))[..., 0]
        return c, root

    def cost(log_n):
        c, root = solve(log_n)
        pred = (A @ c[..., None])[..., 0]
        if objective == "root":
            r = (pred - root) * use
        else:
            r = (positive_power(pred, np.exp(log_n)[:, None]) - np.where(use, lum_s, 0.0)) * use
        return np.einsum("ts,ts->t", r, r)

    T = lum_s.shape[0]
    lo, hi = np.full(T, np.log(bracket[0])), np.full(T, np.log(bracket[1]))
    log_n, f = brent_minimize(cost, lo, hi, iterations=iterations)
    c, _ = solve(log_n)
    if not anisotropic:
        c = np.stack([c[:, 0], c[:, 0], c[:, 1]], axis=-1)
    return c, np.exp(log_n), f
