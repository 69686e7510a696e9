"""BRDF interpolation and MIP levels (seed 000 Ch 5), three ways.

Texture filtering, MIP creation, warping and painting all reduce to linear
interpolation of pixels, and a Lafortune texel's parameters are not linear in
the BRDF: the average of two lobes' exponents is not the average lobe.  The
*right* answer for a coarse texel is the BRDF-space average of the fine texels
it covers (Eq 5.1), which no parameter set reproduces exactly; the three
methods approximate it at increasing cost:

``lerp``
    average the parameters (what bilinear/trilinear texture hardware does);
``refit``
    sample–blend–refit (§5.2): evaluate the fine texels at a set of direction
    pairs, average the sampled vectors, fit the model to the average;
``samples``
    per-level refit from the measurements: average the fine texels'
    SampledReflectance (valid samples only) and fit that (notes §10.1, option 1).

:func:`mip_error` measures each against the BRDF-space average over a uniform
direction set.  :func:`blend_sampled` is the sampled-BRDF interpolation itself,
with the validity checks of Eq 5.2–5.16 in :func:`validity_report`.
"""

from __future__ import annotations

import logging

import numpy as np

from sbrdf_core.geometry import fibonacci_hemisphere

logger = logging.getLogger(__name__)


def uniform_pairs(n: int = 16, max_theta_deg: float = 85.0) -> tuple[np.ndarray, np.ndarray]:
    """``(1, n², 3)`` ω_i, ω_r: every ordered pair of ``n`` Fibonacci directions.

    The set is closed under swapping (it holds (a, b) and (b, a)), so reciprocity
    can be checked on vectors sampled with it.
    """
    d = fibonacci_hemisphere(n, max_theta_deg)
    return np.repeat(d, n, axis=0)[None], np.tile(d, (n, 1))[None]


def _eval(model, params, wi, wo):
    T = next(iter(params.values())).shape[0]
    return model.eval({k: np.asarray(v, np.float64) for k, v in params.items()},
                      np.broadcast_to(wi, (T,) + wi.shape[1:]), np.broadcast_to(wo, (T,) + wo.shape[1:]))


# -- sampled-BRDF space ---------------------------------------------------------------------------


def blend_sampled(vectors: np.ndarray, weights) -> np.ndarray:
    """Σ_k w_k f_k for sampled BRDFs ``vectors`` ``(K, ...)``: interpolation (w ≥ 0, Σ = 1) or not."""
    w = np.asarray(weights, np.float64)
    if w.shape != (len(vectors),):
        raise ValueError(f"{len(vectors)} sampled BRDFs but {w.shape} weights")
    return np.tensordot(w, np.asarray(vectors, np.float64), axes=1)


def validity_report(f: np.ndarray, wi: np.ndarray, wo: np.ndarray, tol: float = 1e-9) -> dict:
    """Checks of Eq 5.3–5.16 on a sampled BRDF ``f`` ``(S, C)`` at pairs ``wi``, ``wo`` ``(S, 3)``.

    ``min``: smallest value (non-negativity); ``reciprocity``: largest |f(a→b) − f(b→a)|
    over the pairs whose swap is in the set; ``energy``: largest discrete Σ_r f cos θ_r · Δω
    over ω_i (Eq 5.10 with the quadrature weight 2π(1 − cos θ_max)/N_r the text leaves out).
    """
    f = np.asarray(f, np.float64)
    key = {(tuple(np.round(a, 9)), tuple(np.round(b, 9))): s for s, (a, b) in enumerate(zip(wi, wo))}
    pairs = [(s, key[(tuple(np.round(b, 9)), tuple(np.round(a, 9)))]) for (a, b), s in zip(zip(wi, wo), range(len(wi)))
             if (tuple(np.round(b, 9)), tuple(np.round(a, 9))) in key]
    s1, s2 = np.array(pairs).T if pairs else (np.zeros(0, int), np.zeros(0, int))
    recip = float(np.abs(f[s1] - f[s2]).max()) if len(s1) else float("nan")
    # energy: group by ω_i
    _, group = np.unique(np.round(wi, 9), axis=0, return_inverse=True)
    n_r = np.bincount(group.ravel())
    cos_max = wo[:, 2].min()
    domega = 2 * np.pi * (1 - cos_max) / n_r[group.ravel()]
    albedo = np.zeros((len(n_r), f.shape[-1]))
    np.add.at(albedo, group.ravel(), f * (wo[:, 2] * domega)[:, None])
    return {"min": float(f.min()), "non_negative": bool(f.min() >= -tol), "reciprocity": recip,
            "reciprocal": bool(recip <= tol * max(1.0, np.abs(f).max())), "energy": float(albedo.max())}


# -- MIP levels -----------------------------------------------------------------------------------


def _blocks(a: np.ndarray) -> np.ndarray:
    """``(V, U, ...)`` -> ``(V/2, U/2, 4, ...)``: the 2×2 children of each coarse texel (odd edges dropped)."""
    V, U = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
    a = a[:V, :U]
    b = a.reshape(V // 2, 2, U // 2, 2, *a.shape[2:])
    return np.moveaxis(b, 2, 1).reshape(V // 2, U // 2, 4, *a.shape[2:])


def brdf_average(model, params: dict, n_dirs: int = 16) -> np.ndarray:
    """The reference: each coarse texel's BRDF-space average of its 2×2 children, ``(V/2, U/2, S, 3)``."""
    wi, wo = uniform_pairs(n_dirs)
    V, U = next(iter(params.values())).shape[:2]
    f = _eval(model, {k: v.reshape(V * U, -1) for k, v in params.items()}, wi, wo)
    return _blocks(f.reshape(V, U, *f.shape[1:])).mean(axis=2)


def mip_lerp(params: dict) -> dict:
    """Average the parameters of each 2×2 block (hardware filtering of parameter textures)."""
    return {k: _blocks(np.asarray(v, np.float64)).mean(axis=2) for k, v in params.items()}


def _fit(model, f, valid, wi, wo, starts_from=None, iterations=50):
    """LM fit, from the model's initial guess and (if given) from ``starts_from``; each texel keeps the better."""
    from sbrdf_lib.lm import fit_model

    params, _, cost = fit_model(model, f, valid, wi, wo, iterations=iterations)
    if starts_from is not None:
        form = model.fit_form()
        alt, _, cost2 = fit_model(model, f, valid, wi, wo, iterations=iterations, initial=form.from_model(starts_from))
        better = cost2 < cost
        params = {k: np.where(better[:, None], alt[k], params[k]) for k in params}
    return params


def mip_refit(model, params: dict, n_dirs: int = 12, iterations: int = 50) -> dict:
    """Sample–blend–refit: fit each coarse texel to the average of its children's sampled BRDFs."""
    wi, wo = uniform_pairs(n_dirs)
    target = brdf_average(model, params, n_dirs)
    Vc, Uc = target.shape[:2]
    T = Vc * Uc
    lerp = {k: v.reshape(T, -1) for k, v in mip_lerp(params).items()}
    f = target.reshape(T, *target.shape[2:])
    logger.debug("mip refit of %d coarse texels (%s)", T, model.name)
    fit = _fit(model, f, np.ones(f.shape[:2], bool), np.broadcast_to(wi, (T,) + wi.shape[1:]),
               np.broadcast_to(wo, (T,) + wo.shape[1:]), lerp, iterations)
    return {k: v.reshape(Vc, Uc, -1) for k, v in fit.items()}


def downsample_samples(f_r: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A SampledReflectance one level down: 2×2 means of the valid samples, ``(V/2, U/2, P, 3)`` and validity.

    A coarse sample is valid where any child's is; children without a valid sample
    do not pull the mean to zero.
    """
    w = _blocks(valid.astype(np.float64))  # (Vc, Uc, 4, P)
    s = (_blocks(np.where(valid[..., None], f_r, 0.0)) * w[..., None]).sum(axis=2)
    n = w.sum(axis=2)
    return s / np.maximum(n, 1)[..., None], n > 0


def mip_refit_samples(model, f_r: np.ndarray, valid: np.ndarray, texels, size_mm, light_pos, camera_pos,
                      iterations: int = 50, starts_from: dict | None = None) -> dict:
    """Per-level refit: fit the coarse texels to the downsampled measurements, at the coarse texels' directions."""
    from sbrdf_core.geometry import tile_directions

    fc, vc = downsample_samples(f_r, valid)
    Vc, Uc = fc.shape[:2]
    wi, _, wo = tile_directions((Uc, Vc), size_mm, (0, Vc), (0, Uc), light_pos, camera_pos)
    T = Vc * Uc
    start = None if starts_from is None else {k: v.reshape(T, -1) for k, v in starts_from.items()}
    fit = _fit(model, fc.reshape(T, *fc.shape[2:]), vc.reshape(T, -1), wi, wo, start, iterations)
    return {k: v.reshape(Vc, Uc, -1) for k, v in fit.items()}


def mip_error(model, coarse: dict, reference: np.ndarray, n_dirs: int = 16) -> np.ndarray:
    """Per coarse texel RMS (sr⁻¹) of ``coarse`` against the BRDF-space average ``reference``."""
    wi, wo = uniform_pairs(n_dirs)
    Vc, Uc = reference.shape[:2]
    f = _eval(model, {k: np.asarray(v).reshape(Vc * Uc, -1) for k, v in coarse.items()}, wi, wo)
    return np.sqrt(np.mean((f.reshape(reference.shape) - reference) ** 2, axis=(2, 3)))
