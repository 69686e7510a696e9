"""The fitting engine's compiled loops, written once for every model.

This module is a template.  :mod:`sbrdf_core.engine` copies it into the
kernel cache with the line marked ``KERNEL`` replaced by an import of one
model's fit kernel (``fit_kernel(x, cfg, wi, wo, f, J)``: f_r and its
Jacobian in the model's fit form at one direction pair), so numba compiles
these loops once per model and caches them on disk like any other module.
Imported as it stands, ``kernel`` is a stand-in and nothing here is compiled.

Invariants every function keeps:

- the objective of texel t is ``Σ_s Σ_c (w[t, s] (f(x; wi, wo)_c − f_r[t, s, c]))²``;
  a sample with weight 0 is never evaluated;
- parameters with ``free[k] == 0`` never move, and every iterate stays in
  the per-texel box ``lo[t] ≤ x ≤ hi[t]``;
- texels are independent and the loops hold no GIL: :mod:`sbrdf_core.engine` runs slices of texels on
  several threads at once.
"""

import math

import numpy as np
from numba import njit

kernel = None  # KERNEL: the cached copy imports the model's fit kernel on this line


@njit(cache=True, nogil=True)
def normal_equations(x, cfg, f_r, w, wi, wo, t, free, A, g, f, J):
    """Fill ``A = JᵀJ`` and ``g = Jᵀr`` of texel ``t`` at ``x`` (weighted, fixed parameters zeroed); return the cost."""
    K = x.size
    nc = f_r.shape[2]
    for a in range(K):
        g[a] = 0.0
        for b in range(K):
            A[a, b] = 0.0
    cost = 0.0
    for s in range(f_r.shape[1]):
        ws = w[t, s]
        if ws == 0.0:
            continue
        kernel(x, cfg, wi[t, s], wo[t, s], f, J)
        for c in range(nc):
            r = (f[c] - f_r[t, s, c]) * ws
            cost += r * r
            for a in range(K):
                ja = J[c, a] * ws
                if ja == 0.0:
                    continue  # magnitude columns are zero outside their channel: most of J
                g[a] += ja * r
                ja *= ws
                for b in range(a, K):
                    A[a, b] += ja * J[c, b]
    for a in range(K):
        if free[a] == 0:
            g[a] = 0.0
            for b in range(K):
                A[a, b] = 0.0
                A[b, a] = 0.0
        for b in range(a):
            A[a, b] = A[b, a]
    return cost


@njit(cache=True, nogil=True)
def texel_cost(x, cfg, f_r, w, wi, wo, t, f, J):
    """The objective of texel ``t`` at ``x`` (NaN where the model gives a non-finite value)."""
    cost = 0.0
    for s in range(f_r.shape[1]):
        ws = w[t, s]
        if ws == 0.0:
            continue
        kernel(x, cfg, wi[t, s], wo[t, s], f, J)
        for c in range(f_r.shape[2]):
            r = (f[c] - f_r[t, s, c]) * ws
            cost += r * r
    return cost


@njit(cache=True, nogil=True)
def damped_step(A, g, lam, free, pinned, M, step):
    """Solve ``(A + λ diag A) step = −g`` over the free, unpinned parameters by Cholesky; False if it fails."""
    K = g.size
    for a in range(K):
        use_a = free[a] != 0 and not pinned[a]
        for b in range(K):
            M[a, b] = A[a, b] if (use_a and free[b] != 0 and not pinned[b]) else 0.0
        if use_a:
            M[a, a] += lam * max(A[a, a], 1e-12)
            step[a] = -g[a]
        else:
            M[a, a] = 1.0
            step[a] = 0.0
    # In-place Cholesky M = L Lᵀ (lower triangle), then the two triangular solves.
    for j in range(K):
        d = M[j, j]
        for k in range(j):
            d -= M[j, k] * M[j, k]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        M[j, j] = d
        for i in range(j + 1, K):
            v = M[i, j]
            for k in range(j):
                v -= M[i, k] * M[j, k]
            M[i, j] = v / d
    for i in range(K):
        v = step[i]
        for k in range(i):
            v -= M[i, k] * step[k]
        step[i] = v / M[i, i]
    for i in range(K - 1, -1, -1):
        v = step[i]
        for k in range(i + 1, K):
            v -= M[k, i] * step[k]
        step[i] = v / M[i, i]
    for i in range(K):
        if not math.isfinite(step[i]):
            return False
    return True


@njit(cache=True, nogil=True)
def box_step(x, A, g, lam, free, lo, hi, pinned, M, step):
    """The damped step from ``x``, solved again without the parameters it would push out of the box from its
    bound (an active set); False where the system cannot be solved."""
    for k in range(x.size):
        pinned[k] = False
    if not damped_step(A, g, lam, free, pinned, M, step):
        return False
    again = False
    for k in range(x.size):
        out_low = x[k] + step[k] < lo[k] and x[k] <= lo[k] + 1e-12 * max(abs(lo[k]), 1.0)
        out_high = x[k] + step[k] > hi[k] and x[k] >= hi[k] - 1e-12 * max(abs(hi[k]), 1.0)
        if free[k] != 0 and (out_low or out_high):
            pinned[k] = True
            again = True
    return damped_step(A, g, lam, free, pinned, M, step) if again else True


@njit(cache=True, nogil=True)
def trial_point(x, step, lo, hi, max_step, trial):
    """``x + step`` shortened along its direction to ``max_step`` per parameter, then clipped to the box."""
    scale = 1.0
    for k in range(x.size):
        size = abs(step[k])
        if size > max_step[k]:
            scale = min(scale, max_step[k] / size)
    for k in range(x.size):
        trial[k] = min(max(x[k] + scale * step[k], lo[k]), hi[k])


@njit(cache=True, nogil=True)
def solve(cfg, x0, lo, hi, free, max_step, f_r, w, exact, wi, wo, iterations, tolerance, damping, max_damping,
          x_out, cost_out, converged_out, iterations_out):
    """Levenberg–Marquardt from ``x0`` for every texel, inside its box ``[lo, hi]``.

    Per texel: Marquardt's diagonal damping, shrunk ÷3 on an accepted step
    and grown ×4 on a rejected one; a parameter at its bound whose step
    points out of the box is frozen and the step solved again without it (an
    active set), so the others take the constrained step at once instead of
    crawling along the bound.  A texel stops when an accepted step gains less
    than ``tolerance`` of its cost, a rejected step was already negligible,
    λ passes ``max_damping`` (no descent direction left) or its cost is below
    ``exact[t]`` (an exact fit to round-off); those are converged.  A texel that
    uses all ``iterations`` is not.
    """
    T, K = x0.shape
    nc = f_r.shape[2]
    for t in range(T):
        x = np.empty(K)
        for k in range(K):
            x[k] = min(max(x0[t, k], lo[t, k]), hi[t, k])
        A = np.empty((K, K))
        A2 = np.empty((K, K))
        M = np.empty((K, K))
        g = np.empty(K)
        g2 = np.empty(K)
        step = np.empty(K)
        trial = np.empty(K)
        pinned = np.zeros(K, np.bool_)
        f = np.empty(nc)
        J = np.empty((nc, K))
        cost = normal_equations(x, cfg, f_r, w, wi, wo, t, free, A, g, f, J)
        lam = damping
        done = not (cost > exact[t]) or not math.isfinite(cost)
        used = 0
        while not done and used < iterations:
            used += 1
            if not box_step(x, A, g, lam, free, lo[t], hi[t], pinned, M, step):
                lam *= 4.0
                if lam > max_damping:
                    done = True
                continue
            trial_point(x, step, lo[t], hi[t], max_step, trial)
            new_cost = normal_equations(trial, cfg, f_r, w, wi, wo, t, free, A2, g2, f, J)
            if math.isfinite(new_cost) and new_cost < cost:
                gain = (cost - new_cost) / max(cost, 1e-300)
                for k in range(K):
                    x[k] = trial[k]
                    g[k] = g2[k]
                    for b in range(K):
                        A[k, b] = A2[k, b]
                cost = new_cost
                lam = max(lam / 3.0, 1e-12)
                done = gain < tolerance or cost <= exact[t]
            else:
                size = 0.0
                scale = 1e-12
                for k in range(K):
                    size = max(size, abs(trial[k] - x[k]))
                    scale = max(scale, abs(x[k]))
                lam *= 4.0
                done = size <= 1e-9 * scale or lam > max_damping
        for k in range(K):
            x_out[t, k] = x[k]
        cost_out[t] = cost
        converged_out[t] = done
        iterations_out[t] = used


@njit(cache=True, nogil=True)
def costs(cfg, x, f_r, w, wi, wo, out):
    """The objective of every texel at its row of ``x``: ``out[t]``."""
    T, K = x.shape
    nc = f_r.shape[2]
    for t in range(T):
        f = np.empty(nc)
        J = np.empty((nc, K))
        out[t] = texel_cost(x[t], cfg, f_r, w, wi, wo, t, f, J)


@njit(cache=True, nogil=True)
def all_normal_equations(cfg, x, rows, free, f_r, w, wi, wo, A_out, g_out, cost_out):
    """:func:`normal_equations` of texels ``rows`` at the rows of ``x``, for the NumPy loop's refinements."""
    n, K = x.shape
    nc = f_r.shape[2]
    for i in range(n):
        f = np.empty(nc)
        J = np.empty((nc, K))
        cost_out[i] = normal_equations(x[i], cfg, f_r, w, wi, wo, rows[i], free, A_out[i], g_out[i], f, J)


@njit(cache=True, nogil=True)
def evaluate(cfg, x, wi, wo, out):
    """f_r of every texel at its row of ``x`` for each of its direction pairs: ``out[t, s, :]``."""
    T, S = wi.shape[0], wi.shape[1]
    K = x.shape[1]
    nc = out.shape[2]
    f = np.empty(nc)
    J = np.empty((nc, K))
    for t in range(T):
        for s in range(S):
            kernel(x[t], cfg, wi[t, s], wo[t, s], f, J)
            for c in range(nc):
                out[t, s, c] = f[c]
