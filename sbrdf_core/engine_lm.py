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
- where the form has a projection kernel (``project(x, cfg, lim[t], lo[t], hi[t])``, in place: the form's
  ``constrain`` on one packed row) every iterate is its projection;
- where a texel has a peak bound (``log_bound[t]`` finite and ``widths`` not empty), every iterate's mirror
  peak (the largest f_r·``cos2`` over the mirror pairs ``mi``, ``mo``) is at most the bound: the ``widths``
  parameters (logarithms of the model's roughness) are raised by one common amount until it is
  (:func:`widen`, the compiled :func:`~sbrdf_core.constraints.widen_to_peak`);
- texels are independent and the loops hold no GIL: :mod:`sbrdf_core.engine` runs slices of texels on
  several threads at once.
"""

import math
from typing import Any

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def project(x, cfg, lim, lo, hi):  # pragma: no cover (stands in where the form has no projection kernel)
    return False


# The cached copy imports the model's fit kernel (and its projection kernel, replacing the stand-in) here:
kernel: Any = None  # KERNEL: the cached copy imports the model's fit kernel on this line


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
def cholesky_solve(M, v):
    """Solve ``L Lᵀ u = v`` in place, ``L`` the lower triangle of ``M`` (a Cholesky factor)."""
    K = v.size
    for i in range(K):
        a = v[i]
        for k in range(i):
            a -= M[i, k] * v[k]
        v[i] = a / M[i, i]
    for i in range(K - 1, -1, -1):
        a = v[i]
        for k in range(i + 1, K):
            a -= M[k, i] * v[k]
        v[i] = a / M[i, i]


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
    cholesky_solve(M, step)
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
def mirror_peak(x, cfg, mi, mo, cos2, f, J, grad):
    """log of the largest f_r·``cos2`` over the mirror pairs at ``x`` (inf where a value is not finite, −inf
    where none is positive); with ``grad`` (length K, or 0 to skip) filled by that log's gradient at the
    pair and channel where the maximum is."""
    best, at, ch = -np.inf, -1, -1
    for p in range(mi.shape[0]):
        kernel(x, cfg, mi[p], mo[p], f, J)
        for c in range(f.size):
            v = f[c] * cos2[p]
            if not math.isfinite(v):
                return np.inf
            if v > best:
                best, at, ch = v, p, c
    if not best > 0.0:
        return -np.inf
    if grad.size:
        kernel(x, cfg, mi[at], mo[at], f, J)
        for k in range(grad.size):
            grad[k] = J[ch, k] / f[ch]
    return math.log(best)


@njit(cache=True, nogil=True)
def _widened(x, widths, hi, factor, trial):
    for k in range(x.size):
        trial[k] = x[k]
    for i in range(widths.size):
        k = widths[i]
        trial[k] = min(x[k] + factor, hi[k])


@njit(cache=True, nogil=True)
def widen(x, cfg, widths, hi, log_bound, mi, mo, cos2, f, J, trial, tolerance=1e-4, steps=16):
    """Raise the ``widths`` entries of ``x`` (in place, each capped at ``hi``) by one common amount until the
    mirror peak is within ``log_bound``: regula falsi on the log peak (Illinois), as
    :func:`~sbrdf_core.constraints.widen_to_peak` does for a batch.  Ends within ``tolerance`` below the
    bound, on the side that fits; a texel over it even at the widest keeps the widest.  True if ``x`` moved."""
    none = np.empty(0)
    g_lo = mirror_peak(x, cfg, mi, mo, cos2, f, J, none) - log_bound
    if not g_lo > math.log1p(1e-6):  # within the bound (NaN: nothing to compare)
        return False
    room = 0.0
    for i in range(widths.size):
        room = max(room, hi[widths[i]] - x[widths[i]])
    a, b = 0.0, room
    _widened(x, widths, hi, b, trial)
    g_hi = mirror_peak(trial, cfg, mi, mo, cos2, f, J, none) - log_bound
    if g_hi < -tolerance and math.isfinite(g_hi):
        side = 0
        for _ in range(steps):
            if math.isfinite(g_lo):
                mid = a + (b - a) * g_lo / (g_lo - g_hi)
            else:  # an infinite peak at the narrow end: bisect
                mid = 0.5 * (a + b)
            mid = min(max(mid, a + 1e-3 * (b - a)), b - 1e-3 * (b - a))
            _widened(x, widths, hi, mid, trial)
            g = mirror_peak(trial, cfg, mi, mo, cos2, f, J, none) - log_bound
            if math.isnan(g):
                g = np.inf
            fits = g <= 0.0
            if fits:
                b, g_hi = mid, g
                if side == 1:  # Illinois: the end that stays twice has its value halved
                    g_lo *= 0.5
                side = 1
            else:
                a, g_lo = mid, g
                if side == -1:
                    g_hi *= 0.5
                side = -1
            if (fits and g > -tolerance) or b - a < 1e-9:
                break
    if b <= 1e-9:
        return False
    _widened(x, widths, hi, b, trial)
    for k in range(x.size):
        x[k] = trial[k]
    return True


@njit(cache=True, nogil=True)
def along_bound(M, grad, free, pinned, step, y):
    """The damped ``step`` made tangent to an active peak bound whose log has gradient ``grad``.

    ``M`` holds the Cholesky factor :func:`damped_step` left.  Where the step would raise the peak, it is
    replaced by the minimiser of the same damped model on the plane ``grad · step = 0``:
    ``step − M⁻¹grad (grad·step) / (grad·M⁻¹grad)``.  Why: LM steps that leave the bound and are widened
    back move a fraction of the way each time, and a texel held by its peak crawls along the bound for
    tens of iterations; the tangent step follows it.
    """
    K = step.size
    along = 0.0
    for k in range(K):
        y[k] = grad[k] if (free[k] != 0 and not pinned[k]) else 0.0
        along += y[k] * step[k]
    if not along > 0.0:
        return
    cholesky_solve(M, y)
    denom = 0.0
    for k in range(K):
        denom += (grad[k] if (free[k] != 0 and not pinned[k]) else 0.0) * y[k]
    if denom > 0.0 and math.isfinite(denom):
        for k in range(K):
            step[k] -= y[k] * along / denom


@njit(cache=True, nogil=True)
def projected_step(x, A, g, lam, free, lo, hi, max_step, cfg, lim, pinned, M, step, trial):
    """``trial`` (the box's trial point from ``step``) through the form's projection; where that held a free
    parameter where it was while the step pointed away, the step is solved again with it frozen and projected."""
    raw = trial.copy()
    project(trial, cfg, lim, lo, hi)
    again = False
    for k in range(x.size):
        scale = 1e-9 * max(abs(x[k]), 1.0)
        if free[k] != 0 and not pinned[k] and abs(trial[k] - raw[k]) > scale and abs(trial[k] - x[k]) <= scale:
            pinned[k] = True
            again = True
    if again and damped_step(A, g, lam, free, pinned, M, step):
        trial_point(x, step, lo, hi, max_step, trial)
        project(trial, cfg, lim, lo, hi)


#: Below the bound by less than this (in log), a texel's peak bound is active: its steps go along it.
ON_BOUND = 1e-3


@njit(cache=True, nogil=True)
def project_moves(x, cfg, lim, lo, hi, before):
    """Project ``x`` in place (the form's kernel); True if that moved it (``before``: scratch)."""
    for k in range(x.size):
        before[k] = x[k]
    project(x, cfg, lim, lo, hi)
    for k in range(x.size):
        if abs(x[k] - before[k]) > 1e-9 * (1.0 + abs(before[k])):
            return True
    return False


@njit(cache=True, nogil=True)
def held_to_peak(x, cfg, widths, hi, log_bound, mi, mo, cos2, f, J, grad, scratch):
    """``x`` widened to the peak bound (in place, :func:`widen`); True where the bound is active there, with
    ``grad`` its log's gradient.  No ``widths``: no bound, False."""
    if widths.size == 0:
        return False
    widen(x, cfg, widths, hi, log_bound, mi, mo, cos2, f, J, scratch)
    return mirror_peak(x, cfg, mi, mo, cos2, f, J, grad) > log_bound - ON_BOUND


@njit(cache=True, nogil=True)
def descend(t, x, cfg, lo, hi, free, max_step, f_r, w, exact, wi, wo, iterations, tolerance, damping, max_damping,
            widths, log_bound, mi, mo, cos2, proj, lim, work):
    """One Levenberg–Marquardt run of texel ``t`` from ``x`` (updated in place) inside its box ``lo``, ``hi``, as
    :func:`solve` describes; ``widths`` empty: no peak bound.  Returns ``(cost, converged, iterations)``."""
    A, A2, M, g, g2, step, trial, pinned, f, J, grad, grad2, y = work
    K = x.size
    on_bound = held_to_peak(x, cfg, widths, hi, log_bound, mi, mo, cos2, f, J, grad, trial)
    cost = normal_equations(x, cfg, f_r, w, wi, wo, t, free, A, g, f, J)
    lam = damping
    done = not (cost > exact) or not math.isfinite(cost)
    n = 0
    while not done and n < iterations:
        n += 1
        if not box_step(x, A, g, lam, free, lo, hi, pinned, M, step):
            lam *= 4.0
            done = lam > max_damping
            continue
        if on_bound:
            along_bound(M, grad, free, pinned, step, y)
        trial_point(x, step, lo, hi, max_step, trial)
        if proj:
            projected_step(x, A, g, lam, free, lo, hi, max_step, cfg, lim, pinned, M, step, trial)
        trial_on_bound = held_to_peak(trial, cfg, widths, hi, log_bound, mi, mo, cos2, f, J, grad2, y)
        new_cost = normal_equations(trial, cfg, f_r, w, wi, wo, t, free, A2, g2, f, J)
        if math.isfinite(new_cost) and new_cost < cost:
            gain = (cost - new_cost) / max(cost, 1e-300)
            for k in range(K):
                x[k] = trial[k]
                g[k] = g2[k]
                grad[k] = grad2[k]
                for b in range(K):
                    A[k, b] = A2[k, b]
            on_bound = trial_on_bound
            cost = new_cost
            lam = max(lam / 3.0, 1e-12)
            done = gain < tolerance or cost <= exact
        else:
            size = 0.0
            scale = 1e-12
            for k in range(K):
                size = max(size, abs(trial[k] - x[k]))
                scale = max(scale, abs(x[k]))
            lam *= 4.0
            done = size <= 1e-9 * scale or lam > max_damping
    return cost, done, n


@njit(cache=True, nogil=True)
def solve(cfg, x0, lo, hi, free, max_step, f_r, w, exact, wi, wo, iterations, tolerance, damping, max_damping,
          widths, log_bound, mi, mo, cos2, projecting, lim, x_out, cost_out, converged_out, iterations_out):
    """Levenberg–Marquardt from ``x0`` for every texel, inside its box ``[lo, hi]``.

    Per texel: Marquardt's diagonal damping, shrunk ÷3 on an accepted step
    and grown ×4 on a rejected one; a parameter at its bound whose step
    points out of the box is frozen and the step solved again without it (an
    active set), so the others take the constrained step at once instead of
    crawling along the bound.  A texel stops when an accepted step gains less
    than ``tolerance`` of its cost, a rejected step was already negligible,
    λ passes ``max_damping`` (no descent direction left) or its cost is below
    ``exact[t]`` (an exact fit to round-off); those are converged.  A texel that
    uses all ``iterations`` is not.  With a peak bound every iterate is widened to it (:func:`widen`), and
    while the bound is active the steps are taken along it (:func:`along_bound`).  With a projection kernel
    (``projecting``) every iterate is projected, and a parameter the projection holds where it was (the step
    pointing out of its bound) is frozen and the step solved again without it, as the box's active set does.
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
        grad = np.empty(K)
        grad2 = np.empty(K)
        y = np.empty(K)
        bounded = widths.size > 0 and math.isfinite(log_bound[t])
        work = (A, A2, M, g, g2, step, trial, pinned, f, J, grad, grad2, y)
        cost, done, used = 0.0, False, 0
        # With a projection: a pass inside the box first, then, where the projection moves its result, a pass
        # with every iterate projected from there.  Why: LM that projects from the start stops early, each
        # projected step gaining little, far from the point the unprojected pass reaches.
        for stage in range(2 if projecting else 1):
            proj = projecting and stage == 1
            if proj and not project_moves(x, cfg, lim[t], lo[t], hi[t], y):
                break
            cost, done, n = descend(t, x, cfg, lo[t], hi[t], free, max_step, f_r, w, exact[t], wi, wo, iterations,
                                    tolerance, damping, max_damping, widths if bounded else widths[:0], log_bound[t],
                                    mi, mo, cos2, proj, lim[t], work)
            used += n
        for k in range(K):
            x_out[t, k] = x[k]
        cost_out[t] = cost
        converged_out[t] = done
        iterations_out[t] = used


@njit(cache=True, nogil=True)
def project_rows(cfg, x, lim, lo, hi, out):
    """The form's projection kernel on every row of ``x`` inside its box row, into ``out``."""
    for t in range(x.shape[0]):
        for k in range(x.shape[1]):
            out[t, k] = x[t, k]
        project(out[t], cfg, lim[t], lo[t], hi[t])


@njit(cache=True, nogil=True)
def widen_rows(cfg, x, lo, hi, widths, log_bound, mi, mo, cos2, channels, out):
    """Every row of ``x`` inside its box row and widened to its peak bound (:func:`widen`; ``log_bound[t]``
    inf: none; −inf, a texel with no support: the widest lobe), into ``out``: the form's ``constrain`` where
    those two are the whole of it."""
    T, K = x.shape
    f = np.empty(channels)
    J = np.empty((channels, K))
    trial = np.empty(K)
    for t in range(T):
        for k in range(K):
            out[t, k] = min(max(x[t, k], lo[t, k]), hi[t, k])
        if widths.size > 0 and log_bound[t] < math.inf:
            widen(out[t], cfg, widths, hi[t], log_bound[t], mi, mo, cos2, f, J, trial)


@njit(cache=True, nogil=True)
def linear_solve(cfg, x, free, lo, hi, f_r, w, wi, wo, out, cost_out):
    """Each texel's ``free`` parameters solved by weighted least squares with the others held (inside
    ``[lo, hi]``), clipped to ``[lo, hi]``, into ``out``, and the objective there into ``cost_out``: one
    Gauss–Newton step, exact where f_r is affine in them (the magnitudes).  A free parameter no sample depends
    on is 0, the least-norm solution (a lobe nothing shows has no magnitude); a texel whose system cannot be
    solved keeps its row of ``x``, clipped."""
    T, K = x.shape
    nc = f_r.shape[2]
    for t in range(T):
        A = np.empty((K, K))
        M = np.empty((K, K))
        g = np.empty(K)
        step = np.zeros(K)
        pinned = np.zeros(K, np.bool_)
        f = np.empty(nc)
        J = np.empty((nc, K))
        x0 = np.empty(K)
        for k in range(K):
            x0[k] = min(max(x[t, k], lo[k]), hi[k])
        cost = normal_equations(x0, cfg, f_r, w, wi, wo, t, free, A, g, f, J)
        ok = math.isfinite(cost) and damped_step(A, g, 1e-12, free, pinned, M, step)
        for k in range(K):
            v = x0[k] + step[k] if ok else x0[k]
            if ok and free[k] != 0 and A[k, k] == 0.0:
                v = 0.0
            out[t, k] = min(max(v, lo[k]), hi[k])
        # f_r is affine in the free parameters and only they moved: the objective at ``out`` is the quadratic
        # the normal equations at ``x0`` describe, cost + 2 gᵀd + dᵀAd, with no further pass over the samples;
        # where its terms cancel to under 10⁻⁸ of their size (absurd magnitudes), the pass is made after all
        quad, size = cost, abs(cost)
        for a in range(K):
            da = out[t, a] - x0[a]
            if da == 0.0:
                continue
            quad += 2.0 * g[a] * da
            size += abs(2.0 * g[a] * da)
            for b in range(K):
                term = da * A[a, b] * (out[t, b] - x0[b])
                quad += term
                size += abs(term)
        if not (quad >= 0.0 and size <= 1e8 * quad):
            quad = texel_cost(out[t], cfg, f_r, w, wi, wo, t, f, J)
        cost_out[t] = quad


@njit(cache=True, nogil=True)
def costs(cfg, x, rows, f_r, w, wi, wo, out):
    """The objective of texel ``rows[i]`` at row ``i`` of ``x``: ``out[i]``."""
    T, K = x.shape
    nc = f_r.shape[2]
    for i in range(T):
        f = np.empty(nc)
        J = np.empty((nc, K))
        out[i] = texel_cost(x[i], cfg, f_r, w, wi, wo, rows[i], f, J)


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
def weighted_sums(cfg, x, wi, wo, weights, out):
    """``out[t, c] = Σ_s weights[s] f_c(x[t]; wi[t], wo[s])``: a quadrature over outgoing directions ``wo``
    ``(S, 3)`` shared by every texel, each from its own ``wi[t]``."""
    T, K = x.shape
    nc = out.shape[1]
    f = np.empty(nc)
    J = np.empty((nc, K))
    for t in range(T):
        for c in range(nc):
            out[t, c] = 0.0
        for s in range(wo.shape[0]):
            if weights[s] == 0.0:
                continue
            kernel(x[t], cfg, wi[t], wo[s], f, J)
            for c in range(nc):
                out[t, c] += weights[s] * f[c]


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
