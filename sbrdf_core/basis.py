"""Basis materials of a tile, in the manner of Lensch et al. 2003: texels clustered, each cluster fitted from all its
texels' samples, each texel refined from its cluster's solution.

A texel's own samples may leave its fit loose (a lobe's peak unsampled, a model that cannot match the material
and settles in one of many compromises), so texels of one material scatter over solutions a render shows as
noise.  A material's texels together sample it far better than any one does.  The Fit node
(``coherence: basis``) therefore, per tile, after the per-texel fit:

1. clusters the texels by their fitted appearance (:func:`features`: log f_r per channel at
   :data:`~sbrdf_core.coherence.APPEARANCE_PAIRS`, the pairs :func:`~sbrdf_core.coherence.cohere` compares)
   into at most ``materials`` clusters with k-means (:func:`kmeans`; 0: as many as stay distinct,
   :func:`cluster`);
2. fits each cluster once to its texels' pooled training samples (at most :data:`POOL`, drawn with a fixed
   seed, so a cluster's fit costs about one texel's fit of that many samples), from the fitter's own starts and
   from the solution of the cluster's most typical texel, keeping the lower pooled cost; clusters that fit
   each other's samples about as well as their own are merged and fitted again, once (:func:`merge`);
3. refits every texel from its cluster's solution (the fitter contract's ``initial``) and takes, per texel,
   the better of that refit and the cluster's solution as it is where it has a lower cost on the texel's own
   training samples than the texel's own solution.

Invariant: a texel's training cost (plain sum of squares over its training samples and channels, each
candidate held to the texel's bounds first) never rises: its own solution is kept unless another is strictly
lower.  The clusters are the tile's (or strip of rows') own: a task sees no other, so label 2 of one tile need
not be label 2 of the next, and a tile that holds few texels of a material fits that material from few samples.
Deterministic: every draw is seeded by a constant, never by time or worker.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .coherence import appearance, training_cost

#: Clusters a tile may have (the ``materials`` parameter's bound), and the most tried when it is 0.
MAX_MATERIALS = 16
#: Training samples a cluster's fit pools at most: enough to pin a lobe many times over, few enough that the
#: clusters' fits cost about as much as a handful of texels' (a fit is linear in its samples).
POOL = 4096
#: k-means++ seedings tried (the lowest within-cluster sum of squares is kept) and Lloyd iterations at most.
KMEANS_STARTS, KMEANS_ITERATIONS = 4, 100
#: With ``materials`` 0: another cluster while every two clusters' centres stay at least this far apart (RMS
#: over :func:`features` of the log difference: about the relative RMS difference of their appearances).  Why
#: not a cut in the within-cluster sum of squares: a material whose samples leave its lobe loose scatters widely
#: (a matte texel's lobe direction is free), and splitting that scatter cuts the sum as much as separating two
#: materials does; its halves' centres, though, stay close.  0.2: four times the outlier distance a texel's
#: neighbours tolerate by default, and above the scatter of a noisy uniform region's fits (a spatial CV under 0.1).
DISTINCT = 0.2
#: Two clusters are one material when each one's solution fits the other's pooled samples within this factor of
#: the other's own cost.  Why 1.5: on the benchmark's four materials every such ratio is over 2.5 (most in the
#: hundreds), and among parts of one noisy material k-means split they stay under 1.15.
SAME_COST = 1.5
#: Appearance below this fraction of the tile's median counts as this fraction (the log of a vanishing lobe's
#: tail would otherwise weigh as much as the difference of two materials).
FLOOR = 1e-3
#: The label of a texel without training samples.
NO_LABEL = -1


def features(model, x: np.ndarray, floor: float | None = None) -> tuple[np.ndarray, float]:
    """``(features, floor)``: ``(T, Q · C)`` log f_r per channel at
    :data:`~sbrdf_core.coherence.APPEARANCE_PAIRS`, floored at ``floor`` (None: :data:`FLOOR` × the median over
    the finite rows); a row with a non-finite value is NaN throughout.  Why log: a Euclidean distance of logs is
    a relative one, so a dark material's texels are told apart as well as a bright one's."""
    look = appearance(model, np.asarray(x, np.float64)).reshape(x.shape[0], -1)
    finite = np.isfinite(look).all(axis=1)
    if floor is None:
        floor = max(FLOOR * float(np.median(np.abs(look[finite]))), 1e-12) if finite.any() else 1e-12
    with np.errstate(invalid="ignore"):
        out = np.log(np.maximum(look, floor))
    out[~finite] = np.nan
    return out, floor


def _sq_distances(f: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``(n, k)`` squared Euclidean distances, without an ``(n, k, D)`` temporary."""
    d = (f * f).sum(axis=1)[:, None] - 2.0 * f @ centres.T + (centres * centres).sum(axis=1)[None]
    return np.maximum(d, 0.0)


def kmeans(f: np.ndarray, k: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(labels, centres)`` of rows ``f`` ``(n, D)`` in at most ``k`` clusters: k-means++ seeding (seeded by
    ``seed``), Lloyd iterations, the best of :data:`KMEANS_STARTS` seedings.  Labels are ``0..m-1`` (m ≤ k: a
    cluster that empties is dropped), numbered by their centre's mean (darkest first), so the same rows give the
    same labels."""
    n = f.shape[0]
    k = max(1, min(k, n))
    rng = np.random.default_rng(seed)
    best: tuple[float, np.ndarray, np.ndarray] = (np.inf, np.zeros(n, np.int64), f[:1])
    for _ in range(KMEANS_STARTS):
        centres = f[[int(rng.integers(n))]]
        for _ in range(1, k):
            d2 = _sq_distances(f, centres).min(axis=1)
            total = d2.sum()
            if not total > 0:  # fewer distinct rows than clusters
                break
            centres = np.vstack([centres, f[int(rng.choice(n, p=d2 / total))]])
        labels = np.full(n, -1)
        for _ in range(KMEANS_ITERATIONS):
            new = _sq_distances(f, centres).argmin(axis=1)
            if np.array_equal(new, labels):
                break
            labels = new
            centres = np.stack([f[labels == j].mean(axis=0) if (labels == j).any() else centres[j]
                                for j in range(centres.shape[0])])
        inertia = float(((f - centres[labels]) ** 2).sum())
        if inertia < best[0]:
            best = (inertia, labels, centres)
    _, labels, centres = best
    used = np.unique(labels)
    order = used[np.argsort(centres[used].mean(axis=1), kind="stable")]
    renumber = np.zeros(centres.shape[0], np.int64)
    renumber[order] = np.arange(order.size)
    return renumber[labels], centres[order]


def cluster(f: np.ndarray, materials: int, seed: int = 0) -> np.ndarray:
    """Labels of rows ``f``: :func:`kmeans` with ``materials`` clusters, or with 0 the most clusters (at most
    :data:`MAX_MATERIALS`) before one more would put two centres closer than :data:`DISTINCT`."""
    if materials > 0:
        return kmeans(f, materials, seed)[0]
    labels = np.zeros(f.shape[0], np.int64)
    for k in range(2, MAX_MATERIALS + 1):
        more, centres = kmeans(f, k, seed)
        if centres.shape[0] < k or _closest(centres) < DISTINCT:
            break
        labels = more
    return labels


def _closest(centres: np.ndarray) -> float:
    """The smallest RMS distance between two rows of ``centres``."""
    d = _sq_distances(centres, centres) / centres.shape[1]
    return float(np.sqrt(d[np.triu_indices(centres.shape[0], 1)].min()))


def merge(cross: np.ndarray) -> np.ndarray:
    """``(m,)`` group of each of ``m`` clusters: clusters each of whose solutions fits the other's pooled samples
    within :data:`SAME_COST` times the other's own cost (``cross[i, j]``: solution i's cost on pool j), directly
    or through others, share one (numbered in order of their first cluster)."""
    m = cross.shape[0]
    own = np.diag(cross)
    with np.errstate(all="ignore"):
        ratio = cross / own[None]
    near = (ratio < SAME_COST) & (ratio.T < SAME_COST)  # NaN and inf: never
    group = np.arange(m)
    for _ in range(m):  # single linkage: the lowest index spreads along the links until nothing changes
        new = np.minimum(group, np.where(near, group[None], m).min(axis=1))
        if np.array_equal(new, group):
            break
        group = new
    return np.unique(group, return_inverse=True)[1]


def pool(groups: list[np.ndarray], f_r: np.ndarray, train: np.ndarray, wi: np.ndarray, wo: np.ndarray,
         limit: int = POOL, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(f_r, valid, wi, wo)`` with one row per group of texels: the group's training samples, at most
    ``limit`` drawn without replacement (seeded by ``seed`` and the group's index), in the order they lie in the
    tile.  Rows are padded with invalid samples at the normal (a zero direction would be NaN to a model, and
    a weight of 0 does not stop NaN)."""
    picks = []
    for j, rows in enumerate(groups):
        t, s = np.nonzero(train[rows])
        if t.size > limit:
            keep = np.sort(np.random.default_rng([seed, j]).choice(t.size, limit, replace=False))
            t, s = t[keep], s[keep]
        picks.append((rows[t], s))
    S = max(1, max(t.size for t, _ in picks))
    k, C = len(groups), f_r.shape[-1]
    pf, pw = np.zeros((k, S, C)), np.zeros((k, S), bool)
    pi, po = np.zeros((k, S, 3)), np.zeros((k, S, 3))
    pi[..., 2] = po[..., 2] = 1.0
    for j, (t, s) in enumerate(picks):
        pf[j, :t.size], pw[j, :t.size], pi[j, :t.size], po[j, :t.size] = f_r[t, s], True, wi[t, s], wo[t, s]
    return pf, pw, pi, po


def basis(model, x: np.ndarray, f_r: np.ndarray, train: np.ndarray, wi: np.ndarray, wo: np.ndarray,
          materials: int, fit: Callable[..., np.ndarray], refit: Callable[[np.ndarray, dict], np.ndarray],
          project: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(x, label, from_basis, refitted)`` for a tile's packed solutions ``x`` ``(T, K)``.

    ``fit(f_r, valid, wi, wo, rows, initial)`` fits pooled samples (one row per cluster) within the bounds of
    texels ``rows`` (one per cluster), from ``initial`` (packed, or None: the fitter's own starts), and returns
    packed solutions; ``refit(rows, initial)`` fits texels ``rows`` from ``initial`` (model form) and returns
    packed solutions; ``project(rows, x)`` holds packed solutions of texels ``rows`` to their bounds.  ``f_r``
    and ``train`` are :func:`~sbrdf_core.nodes.fit.usable`'s.  ``label``: each texel's material, ``0..m-1``
    (:data:`NO_LABEL` without training samples); ``from_basis``: texels whose solution is now their cluster's
    (as it is or refined); ``refitted``: those of them that took the refit (whose fitter flags the caller keeps).
    """
    x = np.array(x, np.float64)
    T = x.shape[0]
    label = np.full(T, NO_LABEL, np.int64)
    from_basis, refitted = np.zeros(T, bool), np.zeros(T, bool)
    has = np.asarray(train.any(axis=1), bool)
    f, floor = features(model, x)
    rows = np.flatnonzero(has & np.isfinite(f).all(axis=1))
    if rows.size <= 1:  # one texel is its own material: its pooled fit would be its own fit again
        label[rows] = 0
        return x, label, from_basis, refitted

    def fit_clusters(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each cluster's solution ``(m, K)`` and each solution's cost on each cluster's pool ``(m, m)``."""
        groups = [rows[labels == j] for j in range(int(labels.max()) + 1)]
        # each cluster's most typical texel (nearest its centre): its bounds and its solution start the fit
        typical = np.array([g[np.argmin(((f[g] - f[g].mean(axis=0)) ** 2).sum(axis=1))] for g in groups])
        pf, pw, pi, po = pool(groups, f_r, train, wi, wo)
        starts = [np.asarray(fit(pf, pw, pi, po, typical, None), np.float64),
                  np.asarray(fit(pf, pw, pi, po, typical, x[typical]), np.float64)]
        cost = [np.where(np.isfinite(c), c, np.inf) for c in (training_cost(model, s, pf, pw, pi, po) for s in starts)]
        solution = np.where((cost[1] < cost[0])[:, None], starts[1], starts[0])
        m = solution.shape[0]
        cross = np.stack([training_cost(model, np.broadcast_to(solution[i], (m, solution.shape[1])), pf, pw, pi, po)
                          for i in range(m)])
        return solution, np.where(np.isfinite(cross), cross, np.inf)

    labels = cluster(f[rows], materials)
    solution, cross = fit_clusters(labels)
    # Reclustered once: clusters that fit each other's samples as well as their own are one material.  k-means
    # splits a material whose texels' fits scatter (a loose lobe, noise) as readily as it separates two, and the
    # parts, each pooled from texels that scatter alike, fit apart and carry that scatter into every texel refined
    # from them.  Their samples, not their loose fits, tell whether they differ.
    same = merge(cross)
    if same.max() + 1 < solution.shape[0]:
        labels = same[labels]
        solution, _ = fit_clusters(labels)
    # numbered darkest first (a failed fit last): the same texels give the same labels
    order = np.argsort(np.nan_to_num(features(model, solution, floor)[0].mean(axis=1), nan=np.inf), kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    label[rows], solution = rank[labels], solution[order]
    m = solution.shape[0]
    ok = np.isfinite(solution).all(axis=1)
    # texels left out of the clustering (a non-finite fit of their own): the cluster whose solution fits them best
    rest = np.flatnonzero(has & (label == NO_LABEL))
    if rest.size:
        costs = np.stack([training_cost(model, np.broadcast_to(solution[j], (rest.size, x.shape[1])), f_r[rest], train[rest],
                                wi[rest], wo[rest]) for j in range(m)], axis=1)
        label[rest] = np.argmin(np.where(np.isfinite(costs) & ok[None], costs, np.inf), axis=1)
    cand = np.flatnonzero(has & ok[np.maximum(label, 0)])
    if cand.size == 0:
        return x, label, from_basis, refitted
    start = solution[label[cand]]
    refined = np.asarray(refit(cand, model.unpack(start)), np.float64)

    def cost(rows: np.ndarray, v: np.ndarray) -> np.ndarray:
        c = training_cost(model, v, f_r[rows], train[rows], wi[rows], wo[rows])
        return np.where(np.isfinite(c), c, np.inf)

    # judged as they will leave the node: held to the texel's bounds, its own solution as `coherence: none` leaves
    # it (a fit outside them often fits clearly worse once held, and then a cluster's solution wins)
    c_o = cost(cand, x[cand] if project is None else project(cand, x[cand]))
    c_r, c_s = cost(cand, refined), cost(cand, start)
    by_refit = c_r <= c_s
    best = np.where(by_refit[:, None], refined, start)
    pick = np.flatnonzero(np.minimum(c_r, c_s) < c_o)
    rows, best = cand[pick], best[pick]
    if project is not None and rows.size:
        # both candidates, held to the bounds (the one better before them is often the worse after), but only
        # where one beats the texel's own before its bounds, which seldom lower a cost: the bounds (an albedo
        # quadrature for some models) cost more than the fits here
        r_p, s_p = project(rows, refined[pick]), project(rows, start[pick])
        cr, cs = cost(rows, r_p), cost(rows, s_p)
        by_refit[pick] = cr <= cs
        best = np.where((cr <= cs)[:, None], r_p, s_p)
        win = np.minimum(cr, cs) < c_o[pick]
        rows, best, pick = rows[win], best[win], pick[win]
    x[rows] = best
    from_basis[rows] = True
    refitted[rows] = by_refit[pick]
    return x, label, from_basis, refitted
