"""Spatial coherence of a tile's fit: neighbours' solutions as restarts, outliers flagged.

A fitter fits each texel alone, so neighbouring texels of one material can
settle in different solutions, and a render shows them as specks: a texel
fitted with a broad lobe among neighbours fitted with a sharp one.  Two cases
make them, and the Fit node (``coherence: neighbours``) treats both with its
texels' neighbours, which are usually the same material:

- **a worse minimum**: a neighbour's solution, evaluated on the texel's own
  training samples, fits them clearly better (cost below ``1 − MARGIN`` times
  the texel's own).  The fitter refines the texel from it (the ``initial``
  keyword of the fitter contract) and the texel keeps the lower of that refit
  and the neighbour's solution as it is.
- **an ambiguous texel**: its samples miss the lobe's peak, so a broad weak
  lobe and a sharp strong one fit them equally well, and the fitter's pick
  differs from its neighbours'.  A texel whose *appearance* (luminance at a
  fixed set of direction pairs, :data:`APPEARANCE_PAIRS`) departs from its
  3×3 neighbourhood's median appearance by more than ``outlier_distance``
  and by more than :data:`ODD_FACTOR` times its neighbours' own departures
  (so a region whose texels all scatter alike singles none out) is refined
  from the neighbour nearest that median.  It takes whichever of that refit
  and that neighbour's solution fits its own samples within the noise (cost
  at most :data:`NOISE_TOLERANCE` parameters' worth of the texel's residual
  variance above its own) and looks most like its neighbourhood.  A texel of another
  material than its neighbours (a boundary, a single-texel feature) fits its
  samples clearly worse from their solution and keeps its own.

Sweeps repeat while a texel changed (at most :data:`SWEEPS`), so a good
solution spreads from texel to texel.  A texel still farther than
``outlier_distance`` from its neighbourhood's appearance is returned as an
outlier for the node to flag.

Invariant: a texel's training cost (plain sum of squares over its training
samples and channels) rises only for an ambiguous texel and then within the
noise; otherwise it changes only to a strictly lower cost.  Neighbours are
those in the same tile (or strip of rows): a task sees no other.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .brdf import evaluate

#: The eight neighbours' offsets (dv, du).
OFFSETS = tuple((dv, du) for dv in (-1, 0, 1) for du in (-1, 0, 1) if dv or du)
#: A neighbour's solution is tried when its cost on the texel's samples is below ``1 − MARGIN`` times the texel's
#: own.  Why not 0: a neighbour of the same material fitted to its own noise scores a few percent either side of
#: the texel's own solution (the fitter minimises a weighted objective, the comparison is plain); refitting those
#: would cost a fit and change nothing a user can see.
MARGIN = 0.1
#: Sweeps at most: each lets a better solution move one texel further.
SWEEPS = 4
#: An ambiguous texel's coherent refit is taken when its cost rises by at most this many times the texel's
#: residual variance (cost / (samples · channels − parameters)) per model parameter: the rise a change of that many
#: parameters within their noise makes (a χ² with K degrees of freedom has mean K).
NOISE_TOLERANCE = 1.0
#: A texel is odd when its departure from its neighbourhood's appearance is over this times the median of its
#: neighbours' departures from theirs (as :func:`specks` judges a value against its neighbours' spread).
ODD_FACTOR = 4.0


def _appearance_pairs(n: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)`` ``(1, n, 3)``: the view at the normal, the light on a Fibonacci spiral up to 75°: how a flat
    sample looks from above under a moving light.  Why not mirror pairs: at the exact peak of a sharp lobe the
    value rests on what samples rarely pin down (Lafortune's |C|ⁿ trades against ρ_s), so texels of one material
    scatter there by tens of percent and an odd texel would not stand out."""
    i = np.arange(n) + 0.5
    z = 1 - (1 - np.cos(np.radians(75))) * i / n
    phi = np.pi * (3 - np.sqrt(5)) * i
    r = np.sqrt(1 - z * z)
    wi = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    return wi[None], np.broadcast_to(np.array([0.0, 0.0, 1.0]), wi.shape)[None]


#: Direction pairs at which texels' appearances are compared.
APPEARANCE_PAIRS = _appearance_pairs()


def training_costs(model, f_r: np.ndarray, train: np.ndarray, wi: np.ndarray, wo: np.ndarray):
    """``cost(x, rows)``: the plain training cost Σ (f_r(x[i]) − f_r)² of each texel ``rows[i]`` at its packed
    model-form row ``x[i]``; by the fit kernel in one compiled pass, the samples read in place, where the model
    has one (no ``(T, S, C)`` arrays), else by ``eval``."""
    from .engine import compiled_problem

    form = model.fit_form()
    problem = compiled_problem(form, f_r, train, wi, wo)

    def cost(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        if problem is not None:
            return problem.cost(x if form is model else form.pack(form.from_model(model.unpack(x))), rows)
        diff = _predict(model, x, wi[rows], wo[rows]) - f_r[rows]
        return np.where(train[rows], (diff * diff).sum(axis=-1), 0.0).sum(axis=1)

    return cost


def training_cost(model, x: np.ndarray, f_r: np.ndarray, train: np.ndarray, wi: np.ndarray, wo: np.ndarray
                  ) -> np.ndarray:
    """Each texel's plain training cost at its packed model-form row of ``x`` (:func:`training_costs`)."""
    return training_costs(model, f_r, train, wi, wo)(x, np.arange(x.shape[0]))


def _predict(model, x: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        return evaluate(model, model.unpack(x), wi, wo)


def appearance(model, x: np.ndarray) -> np.ndarray:
    """``(T, Q, C)`` f_r at :data:`APPEARANCE_PAIRS`."""
    wi, wo = (np.broadcast_to(w, (x.shape[0],) + w.shape[1:]) for w in APPEARANCE_PAIRS)
    return _predict(model, x, wi, wo)


def distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relative RMS distance of appearances ``(..., Q, C)`` (channels summed): 0 alike, about 1 for one lobe
    against none."""
    a, b = a.sum(axis=-1), b.sum(axis=-1)
    with np.errstate(all="ignore"):
        d = np.sqrt(((a - b) ** 2).mean(axis=-1) / np.maximum((0.5 * (a + b)) ** 2, 1e-30).mean(axis=-1))
    return np.where(np.isfinite(d), d, np.inf)


def ring(a: np.ndarray, grid: tuple[int, int], fill: float | None = None) -> np.ndarray:
    """``(8, T, ...)``: each texel's eight neighbours' rows of ``a`` ``(T, ...)`` in :data:`OFFSETS` order; off the
    grid, ``fill`` (None: the edge replicated, as the bounds' 3×3 filters do, ``mode="nearest"``)."""
    V, U = grid
    widths = [(1, 1), (1, 1)] + [(0, 0)] * (a.ndim - 1)
    grid_a = a.reshape((V, U) + a.shape[1:])
    pad = np.pad(grid_a, widths, mode="edge") if fill is None else np.pad(grid_a, widths, constant_values=fill)
    return np.stack([pad[1 + dv:1 + dv + V, 1 + du:1 + du + U].reshape(a.shape) for dv, du in OFFSETS])


def consensus(look: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """Each texel's 3×3 neighbourhood's median appearance ``(T, Q, C)`` (itself included; the edge replicated)."""
    return np.median(np.concatenate([look[None], ring(look, grid)]), axis=0)


def cohere(model, x: np.ndarray, f_r: np.ndarray, train: np.ndarray, wi: np.ndarray, wo: np.ndarray,
           grid: tuple[int, int], refit: Callable[[np.ndarray, dict, np.ndarray], np.ndarray], outlier_distance: float,
           sweeps: int = SWEEPS, margin: float = MARGIN, parent: np.ndarray | None = None,
           project: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(x, from_neighbour, outlier)`` for a tile's packed solutions ``x`` ``(T, K)`` on a ``grid`` of texels.

    ``refit(rows, initial, prior)`` fits texels ``rows`` from ``initial`` (model-form parameters) and returns
    their packed solutions; ``prior`` ``(R, Q, C)`` (NaN rows: none), when given, are extra samples at
    :data:`APPEARANCE_PAIRS` to fit as well: the neighbourhood's median appearance, which pulls an ambiguous
    texel toward its neighbours only where its own samples leave it free.  ``from_neighbour``: texels whose
    solution now comes from a neighbour's (as it is or refined); ``outlier``: texels whose appearance stays farther than ``outlier_distance`` from their
    neighbourhood's (0: no ambiguous-texel step, none flagged).  ``f_r`` and ``train`` are
    :func:`~sbrdf_core.nodes.fit.usable`'s.  ``parent`` ``(T, K)`` (:func:`pyramid`): each texel's parent's
    solution, compared as a neighbour's is.  ``project(rows, x)``: packed solutions of texels ``rows`` onto
    their bounds (the node's :func:`~sbrdf_core.constraints.enforce`), so that a solution is taken for the cost
    it will have, not for one its bounds will take away.
    """
    x = np.array(x, np.float64)
    T, K = x.shape
    has = np.asarray(train.any(axis=1), bool)
    cost_of = training_costs(model, f_r, train, wi, wo)
    own = cost_of(x, np.arange(T))
    cost = np.where(has & np.isfinite(own), own, np.inf)
    dof = np.maximum(train.sum(axis=1) * f_r.shape[-1] - K, 1)
    # the noise allowance is the texel's own fit's, once: sweeps must not add it up
    allowed = cost + NOISE_TOLERANCE * K * cost / dof
    moved = np.zeros(T, bool)
    look = appearance(model, x)
    dev = np.zeros(T)
    # Texels whose outcome can differ from the last sweep's: at first all; then those within two texels of one
    # that moved (a candidate is a neighbour's solution, and oddness reads the neighbours' consensus, which
    # reads theirs).  Elsewhere the sweep would score the same candidates against the same costs again.
    active = np.ones(T, bool)
    for sweep in range(sweeps + 1):
        middle = consensus(look, grid)
        dev = distance(look, middle)
        odd = _odd(dev, has, grid, outlier_distance) & active
        best_cost, best_x = cost * (1 - margin), x.copy()
        near, near_x = np.full(T, np.inf), np.full_like(x, np.nan)
        # the coherent candidates: the parent's solution (coarse to fine, first sweep only), then each neighbour's
        candidates = [(parent, None)] if parent is not None and sweep == 0 else []
        candidates += zip(ring(x, grid, fill=np.nan), ring(look, grid, fill=np.nan))
        for xn, ln in candidates:
            rows = np.flatnonzero(active & has & np.isfinite(xn).all(axis=1))
            if rows.size == 0:
                continue
            c = cost_of(xn[rows], rows)
            better = c < best_cost[rows]
            best_cost[rows[better]], best_x[rows[better]] = c[better], xn[rows[better]]
            if ln is None:  # the parent is no neighbour to look like
                continue
            d = distance(ln[rows], middle[rows])
            closer = odd[rows] & (d < near[rows])
            near[rows[closer]], near_x[rows[closer]] = d[closer], xn[rows[closer]]
        better = best_cost < cost * (1 - margin)
        ambiguous = odd & ~better & np.isfinite(near)
        cand = np.flatnonzero(better | ambiguous)
        if cand.size == 0 or sweep == sweeps:
            break
        start = np.where(better[cand, None], best_x[cand], near_x[cand])
        prior = np.where(better[cand, None, None], np.nan, middle[cand])
        refined = np.asarray(refit(cand, model.unpack(start), prior), np.float64)
        if project is not None:  # judged as they will leave the node: inside the texel's own bounds
            start, refined = project(cand, start), project(cand, refined)
        c_r, c_s = (cost_of(v, cand) for v in (refined, start))
        c_r, c_s = (np.where(np.isfinite(v), v, np.inf) for v in (c_r, c_s))
        b = better[cand]
        # a worse minimum: the lower of the refit and the neighbour's solution, if lower than the texel's own
        take_refit = b & (c_r <= c_s) & (c_r < cost[cand])
        take_start = b & ~take_refit & (c_s < cost[cand])
        # an ambiguous texel: whichever of the two fits within the noise and looks most like its neighbourhood
        limit = allowed[cand]
        d_r = np.where(c_r <= limit, distance(appearance(model, refined), middle[cand]), np.inf)
        d_s = np.where(c_s <= limit, near[cand], np.inf)
        take_refit |= ~b & (d_r < dev[cand]) & (d_r <= d_s)
        take_start |= ~b & (d_s < dev[cand]) & (d_s < d_r)
        rows = cand[take_refit | take_start]
        if rows.size == 0:
            break
        new_x = np.where(take_refit[:, None], refined, start)[take_refit | take_start]
        x[rows] = new_x
        cost[rows] = np.where(take_refit, c_r, c_s)[take_refit | take_start]
        look[rows] = appearance(model, new_x)
        moved[rows] = True
        active = np.zeros(T, bool)
        active[rows] = True
        active = _near(_near(active, grid), grid)
    return x, moved, _odd(dev, has, grid, outlier_distance)


def _near(mask: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """``mask`` grown by one texel in each direction (diagonals included)."""
    return mask | ring(mask, grid, fill=False).any(axis=0)


def _odd(dev: np.ndarray, has: np.ndarray, grid: tuple[int, int], threshold: float) -> np.ndarray:
    """Texels departing from their neighbourhood by over ``threshold`` and :data:`ODD_FACTOR` × their
    neighbours' departures (0: none)."""
    if threshold <= 0:
        return np.zeros(dev.shape, bool)
    typical = np.median(ring(np.where(has, dev, np.inf), grid), axis=0)  # a texel without samples: far off
    return has & (dev > threshold) & (dev > ODD_FACTOR * typical)


def _halve(f_r, train, wi, wo, grid):
    """The next MIP level of a tile's samples: each 2×2 block's valid samples averaged per pose (its directions
    the children's mean), and each texel's block index."""
    V, U = grid
    V2, U2 = (V + 1) // 2, (U + 1) // 2
    v, u = np.divmod(np.arange(V * U), U)
    block = (v // 2) * U2 + u // 2
    T2, S = V2 * U2, f_r.shape[1]
    w = train.astype(np.float64)
    count = np.zeros((T2, S))
    np.add.at(count, block, w)
    total = np.zeros((T2, S, f_r.shape[2]))
    np.add.at(total, block, f_r * w[..., None])
    dirs = []
    for d in (wi, wo):
        mean = np.zeros((T2, S, 3))
        np.add.at(mean, block, d)
        dirs.append(mean / np.maximum(np.linalg.norm(mean, axis=-1, keepdims=True), 1e-12))
    return total / np.maximum(count, 1.0)[..., None], count > 0, dirs[0], dirs[1], (V2, U2), block


def pyramid(fit: Callable, f_r: np.ndarray, train: np.ndarray, wi: np.ndarray, wo: np.ndarray,
            grid: tuple[int, int], limits) -> np.ndarray | None:
    """Each texel's parent's solution ``(T, K)`` from the MIP pyramid of a tile's samples, fitted coarse to
    fine: the top (one texel: the tile's average) with the fitter's own starts, each finer level from its
    parent's solution.  ``fit(f_r, train, wi, wo, limits, initial)`` returns packed solutions (``initial``
    packed, or None).  None for a single texel.  Why: a texel's own starts can miss the basin its region's
    average finds at once, and the pyramid costs about a third of a fit (a level has a quarter of the texels
    of the one below, one start each).  Each coarse texel takes the limits of its first child.
    """
    if grid[0] * grid[1] <= 1:
        return None
    f2, w2, a2, b2, grid2, block = _halve(f_r, train, wi, wo, grid)
    lim2 = None if limits is None else limits.take(np.unique(block, return_index=True)[1])
    above = pyramid(fit, f2, w2, a2, b2, grid2, lim2)
    return np.asarray(fit(f2, w2, a2, b2, lim2, above), np.float64)[block]


def specks(image: np.ndarray, uniform: np.ndarray | None = None, factor: float = 4.0,
           floor: float = 0.01) -> np.ndarray:
    """``(V, U)`` mask of texels whose value departs from their 3×3 neighbourhood's median by more than
    ``factor`` times the neighbourhood's spread: the specks a user sees in a render of a fit.

    ``image`` ``(V, U)`` (or ``(V, U, C)``: luminance-like sum over channels) holds one value per texel, e.g.
    f_r or a render at one light and view direction.  The spread is 1.4826 × the median absolute deviation of
    the eight neighbours from that median (a standard deviation for Gaussian scatter), at least ``floor`` × the
    median, so that a neighbourhood of one noise-free value does not call a rounding error a speck.  Only
    texels whose whole 3×3 neighbourhood lies in ``uniform`` (a mask, default everywhere) and inside the grid
    are judged: at a region's edge a texel differs from its neighbours by right.
    """
    a = np.asarray(image, np.float64)
    if a.ndim == 3:
        a = a.sum(axis=-1)
    V, U = a.shape
    out = np.zeros((V, U), bool)
    if V < 3 or U < 3:
        return out
    around = ring(a.ravel(), (V, U)).reshape(8, V, U)
    median = np.median(np.concatenate([a[None], around]), axis=0)
    spread = np.maximum(1.4826 * np.median(np.abs(around - median), axis=0), floor * np.abs(median))
    with np.errstate(invalid="ignore"):
        odd = ~(np.abs(a - median) <= factor * spread)  # NaN counts as a speck
    if uniform is not None:
        u = np.asarray(uniform, bool)
        odd &= u & ring(u.ravel(), (V, U)).reshape(8, V, U).all(axis=0)
    out[1:-1, 1:-1] = odd[1:-1, 1:-1]  # the grid's edge texels have no whole neighbourhood
    return out
