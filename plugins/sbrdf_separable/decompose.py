"""Separable decompositions of a BRDF sampled on a parameterization's factor grid (seed 001 §4).

The BRDF is a function ``f(wi, wo) -> (M, 3)`` (an analytic model, or
measured samples interpolated: :mod:`.sources`), sampled at the K² × K²
pairs of factor-texel centres (x_i, y_j) of a parameterization:
m_ij = f_P(x_i, y_j).  Rows are produced a block at a time
(:class:`GridSampler`).

- :func:`svd`: the matrix M is formed (K⁴ values per channel: 67 MB in
  float32 at K = 64, 1 GB at K = 128, §4.1) and decomposed per RGB channel;
  the first N singular triples give g_k = √σ_k u_k, h_k = √σ_k v_k, the
  least-squares optimum.  The signs of the first term are chosen positive.
- :func:`nd`: the normalized decomposition (§4.2), one pass over the rows
  per term: g(x) = ‖f_P(x, ·)‖_p (a mean, not an integral: the scale cancels
  in g·h), h(y) = the mean over rows with g > 0 of f_P(x, y)/g(x).  Memory is
  the output factors plus one row block, never M.  Further terms decompose
  the residual f_P − Σ g_j h_j.  A residual is signed, and the text's ND
  averages r/‖r‖ over rows of opposite sign, which cancel: a second term
  made that way barely helps.  ``refine`` streamed power-iteration passes
  per residual term (g = ⟨r, h⟩/⟨h, h⟩, signed; h = Σ g r / Σ g²) fix that.

Grid points whose ω_i or ω_o falls below the horizon (a half/difference
pair (h, d) need not be a real configuration) are never looked up, since
the model is 0 there, so they must not be fitted either: the indicator of
the valid region is not separable, and zeros there cost a 1-term fit of a
constant BRDF 20 % near the horizon; continuing the BRDF (e.g. by mirror
images) puts the specular peak into rows where it does not belong.  They
are treated as missing: ND's first pass averages over valid points only,
then ``impute`` passes fill them with the current estimate of the term
(EM-style; without it the norm of each row covers a different subset and a
separable BRDF is not reproduced exactly).  The SVD fills them with the
1-term ND approximation, then ``impute`` times with its own N-term
reconstruction.  Factor texels with no valid point at all copy their
nearest valid neighbour (bilinear lookups near the rim blend them in).

Non-finite values are 0 and counted (``nonfinite_samples``), and
``clamp_max`` limits the range to [0, clamp_max] (the text uses [0, 5] for
8-bit frame buffers, §6.1).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from .factors import Factors, cell_centres

#: Direction pairs evaluated per row block (bounds the working memory: ~40 float64 temporaries of this size).
BLOCK_PAIRS = 1 << 15

BRDF = Callable[[np.ndarray, np.ndarray], np.ndarray]


def parameterization(name: str, config: dict | None = None, registry=None):
    """A ``parameterization`` plugin instance by name."""
    from sbrdf_core.registry import default_registry

    return (registry or default_registry()).create("parameterization", name, dict(config or {}))


class GridSampler:
    """``f_P(x_i, y_j)`` on a parameterization's K² × K² texel-centre grid, one block of rows at a time."""

    def __init__(self, fn: BRDF, param, size: int, clamp_max: float | None = None, block_pairs: int = BLOCK_PAIRS):
        if size < 2:
            raise ValueError(f"factor size must be at least 2 texels, got {size}")
        self.fn, self.param, self.size, self.clamp_max = fn, param, int(size), clamp_max
        self.centres = cell_centres(self.size)
        self.n = self.size * self.size
        self.rows_per_block = max(1, block_pairs // self.n)
        self.nonfinite = 0

    def blocks(self):
        """``(r0, r1, f (B, K², 3), valid (B, K²))`` for consecutive row blocks."""
        for r0 in range(0, self.n, self.rows_per_block):
            r1 = min(r0 + self.rows_per_block, self.n)
            yield (r0, r1) + self.block(r0, r1)

    def block(self, r0: int, r1: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows ``r0:r1`` of M, ``(B, K², 3)`` float64 (0 where invalid), and the valid mask ``(B, K²)``."""
        wi, wo = self.param.directions(self.centres[r0:r1, None, :], self.centres[None, :, :])
        shape = wi.shape[:2]
        valid = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        with np.errstate(all="ignore"):
            f = np.asarray(self.fn(wi.reshape(-1, 3), wo.reshape(-1, 3)), float).reshape(shape + (3,))
        finite = np.isfinite(f)
        self.nonfinite += int((~finite & valid[..., None]).sum())
        f = np.where(finite & valid[..., None], f, 0.0)
        if self.clamp_max is not None:
            f = np.clip(f, 0.0, self.clamp_max)
        return f, valid


def _fill_empty(a: np.ndarray, has: np.ndarray, size: int) -> np.ndarray:
    """Texels of ``a (K², 3)`` without data (``~has``) take the value of the nearest texel with data."""
    if has.all() or not has.any():
        return a
    from scipy.ndimage import distance_transform_edt

    _, (iv, iu) = distance_transform_edt(~has.reshape(size, size), return_indices=True)
    return a.reshape(size, size, 3)[iv, iu].reshape(-1, 3)


def _nd_terms(blocks, n: int, size: int, terms: int, p: float, impute: int = 1, refine: int = 1):
    """ND terms of the residual, streamed over ``blocks()`` (row blocks ``(r0, r1, f, valid)``).

    Per term: one ND pass over the valid points, ``impute`` ND passes with
    invalid points filled by the current term, and, for residual terms,
    ``refine`` power-iteration passes (g = ⟨r, h⟩/⟨h, h⟩ row by row, h = Σ g r / Σ g²).
    """
    G = np.zeros((terms, n, 3))
    H = np.zeros((terms, n, 3))
    for k in range(terms):
        passes = ["nd"] * (1 + impute) + (["power"] * refine if k else [])
        for it, kind in enumerate(passes):
            g_prev, h_prev = G[k].copy(), H[k].copy()
            num = np.zeros((n, 3))
            den = np.zeros((n, 3))
            row_has = np.zeros(n, bool)
            col_has = np.zeros(n, bool)
            for r0, r1, f, valid in blocks():
                r = f - np.einsum("kbc,kyc->byc", G[:k, r0:r1], H[:k]) if k else f
                if it == 0:
                    r = r * valid[..., None]
                    w = valid.astype(float)
                else:  # invalid points: the current estimate of this term (EM-style completion)
                    r = np.where(valid[..., None], r, g_prev[r0:r1, None, :] * h_prev[None])
                    w = np.ones(valid.shape)
                if kind == "nd":
                    a = np.abs(r)
                    m = np.maximum(a.max(axis=1, keepdims=True), 1e-300)  # scaled: |r|^p neither over- nor underflows
                    g = m[:, 0] * (((a / m) ** p).sum(axis=1) / np.maximum(w.sum(axis=1), 1)[:, None]) ** (1.0 / p)
                    live = g > 1e-150  # 1/g must not overflow
                    num += np.einsum("byc,bc->yc", r, np.where(live, 1.0 / np.where(live, g, 1.0), 0.0))
                    den += np.einsum("by,bc->yc", w, live.astype(float))
                else:
                    hh = np.einsum("yc,yc->c", h_prev, h_prev)
                    g = np.einsum("byc,yc->bc", r, h_prev) / np.where(hh > 0, hh, 1.0)
                    num += np.einsum("byc,bc->yc", r, g)
                    den += (g * g).sum(axis=0)
                G[k, r0:r1] = g
                row_has[r0:r1] = valid.any(axis=1)
                col_has |= valid.any(axis=0)
            H[k] = num / np.where(den > 0, den, 1.0)
            G[k] = _fill_empty(G[k], row_has, size)
            H[k] = _fill_empty(H[k], col_has, size)
    return G, H


def _factors(g, h, sampler: GridSampler, method: str, extra: dict) -> Factors:
    K = sampler.size
    return Factors(g.reshape(-1, K, K, 3), h.reshape(-1, K, K, 3), sampler.param.name, sampler.param.config(),
                   {"method": method, "clamp_max": sampler.clamp_max, "nonfinite_samples": sampler.nonfinite, **extra})


def nd(fn: BRDF, param, size: int, terms: int = 1, p: float = 2.0, clamp_max: float | None = None,
       impute: int = 1, refine: int = 1, block_pairs: int = BLOCK_PAIRS) -> Factors:
    """Normalized decomposition with a p-norm, streamed: memory is the factors plus one row block.

    Each term costs ``1 + impute (+ refine)`` passes over the BRDF samples.
    """
    if terms < 1:
        raise ValueError(f"terms must be at least 1, got {terms}")
    if not p > 0:
        raise ValueError(f"p-norm exponent must be positive, got {p}")
    t0 = time.perf_counter()
    s = GridSampler(fn, param, size, clamp_max, block_pairs)
    G, H = _nd_terms(s.blocks, s.n, s.size, terms, p, impute, refine)
    return _factors(G, H, s, "nd", {"p": p, "impute": impute, "refine": refine, "seconds": time.perf_counter() - t0})


def _truncated_svd(A: np.ndarray, terms: int, solver: str):
    if solver == "dense":
        U, S, Vt = np.linalg.svd(A, full_matrices=False)
        return U[:, :terms].astype(float), S[:terms].astype(float), Vt[:terms].astype(float)
    if not np.any(A):  # ARPACK cannot start from a zero matrix; its decomposition is zero anyway
        return np.zeros((A.shape[0], terms)), np.zeros(terms), np.zeros((terms, A.shape[1]))
    if solver == "arpack":
        from scipy.sparse.linalg import ArpackError, svds

        try:
            U, S, Vt = svds(A, k=min(terms, min(A.shape) - 1), random_state=0)
        except ArpackError:  # no convergence (rank-deficient corner cases): the dense SVD always answers
            return _truncated_svd(A, terms, "dense")
        order = np.argsort(S)[::-1]
        return U[:, order].astype(float), S[order].astype(float), Vt[order].astype(float)
    raise ValueError(f"solver {solver!r}: expected 'dense' or 'arpack'")


def svd(fn: BRDF, param, size: int, terms: int = 1, clamp_max: float | None = None, solver: str = "arpack",
        impute: int = 1, block_pairs: int = BLOCK_PAIRS) -> Factors:
    """Truncated SVD of the full K² × K² matrix per channel (float32, the text's memory figures).

    ``solver``: ``dense`` (LAPACK, all K² triples, then truncated) or ``arpack``
    (the first N triples only; same result, far less time at K ≥ 32).
    """
    if terms < 1:
        raise ValueError(f"terms must be at least 1, got {terms}")
    t0 = time.perf_counter()
    s = GridSampler(fn, param, size, clamp_max, block_pairs)
    if terms >= s.n:
        raise ValueError(f"terms = {terms} must be below K² = {s.n} for a {size}x{size} factor grid")
    G, H, sigma = _svd_terms(s, terms, solver, impute)  # the matrix is released on return
    return _factors(G, H, s, "svd", {"solver": solver, "impute": impute, "singular_values": sigma.tolist(),
                                     "seconds": time.perf_counter() - t0})


def _svd_terms(s: GridSampler, terms: int, solver: str, impute: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``G, H (terms, K², 3)`` and the singular values ``(terms, 3)`` of :func:`svd`, holding the matrix."""
    M = np.empty((3, s.n, s.n), np.float32)
    V = np.empty((s.n, s.n), bool)
    for r0, r1, f, valid in s.blocks():
        M[:, r0:r1, :] = np.moveaxis(f, -1, 0)
        V[r0:r1] = valid

    def from_matrix():
        step = s.rows_per_block
        for r0 in range(0, s.n, step):
            r1 = min(r0 + step, s.n)
            yield r0, r1, np.moveaxis(M[:, r0:r1, :], 0, -1).astype(float), V[r0:r1]

    def fill(G, H):
        for r0 in range(0, s.n, s.rows_per_block):
            r1 = min(r0 + s.rows_per_block, s.n)
            rec = np.einsum("kbc,kyc->cby", G[:, r0:r1], H)
            M[:, r0:r1][:, ~V[r0:r1]] = rec[:, ~V[r0:r1]]

    if not V.all():
        fill(*_nd_terms(from_matrix, s.n, s.size, 1, 2.0, impute=1))
    G = np.zeros((terms, s.n, 3))
    H = np.zeros((terms, s.n, 3))
    sigma = np.zeros((terms, 3))
    for it in range(1 + (impute if not V.all() else 0)):
        if it:
            fill(G, H)
        for c in range(3):
            U, S, Vt = _truncated_svd(M[c], terms, solver)
            flip = np.where(U.sum(axis=0) < 0, -1.0, 1.0)  # the first term positive (§4.1: its signs cancel)
            U, Vt = U * flip, Vt * flip[:, None]
            root = np.sqrt(np.maximum(S, 0.0))
            k = len(S)
            G[:k, :, c] = (U * root).T
            H[:k, :, c] = Vt * root[:, None]
            sigma[:k, c] = S
    return G, H, sigma


def matrix_mb(size: int, itemsize: int = 4) -> float:
    """Memory of one channel's K² × K² matrix, MB (10⁶ bytes): the text's 67 MB at 64, 1 GB at 128."""
    return (size ** 4) * itemsize / 1e6
