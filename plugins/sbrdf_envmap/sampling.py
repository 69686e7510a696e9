"""Mühlbacher's deterministic filtered in-lobe sampling (seed 004 §4.4.3) and the Monte Carlo reference (§4.4.2).

Deterministic sampling places the same few samples inside every pixel's
specular lobe, in the lobe's own coordinates (ξ₁, ξ₂):

- θ_h = (1 − ξ₁)·θ_thresh(φ_h), the lobe cut where the importance sampler
  reaches ξ₁ = ξ_border = 0.01 (Eq 4.10), φ_h from ξ₂ (Eq 4.12, in the
  quadrant-correct atan2 form);
- patterns (:func:`pattern`): centre plus a ring at ξ₁ = 0.6 for isotropic
  lobes, a line along the long axis for strongly anisotropic ones (chosen
  per pixel by the ratio m_y/m_x);
- samples below the horizon are dropped from both sums;
- each sample reads the environment's MIP chain at the level whose texels
  cover the lobe's area divided by the sample count (Eqs 4.14–4.17,
  :func:`footprint_lod`);
- the estimate is the ratio of Eq 4.25 (or 4.23 / 4.24, :func:`estimate`).

For Beckmann lobes the samples are half vectors about the normal reflected
about ω_o (Eqs 4.7, 4.8); for cosine lobes (Lafortune) they are directions
about the peak p̂ at θ = (1 − ξ₁)·θ_thresh with θ_thresh = acos(ξ_border^{1/(n+1)}),
the same construction for the lobe (p̂·ω)^n, whose importance sampler is
cos θ = ξ₁^{1/(n+1)}.

The Monte Carlo reference (:func:`monte_carlo`) integrates the model's own
``eval`` against the unfiltered environment with multiple importance
sampling (balance heuristic) over a cosine-hemisphere sampler and one
sampler per lobe, on scrambled Sobol points rotated per pixel: unbiased,
converging, and deterministic for a given seed.
"""

from __future__ import annotations

import numpy as np

XI_BORDER = 0.01
RING_RADIUS = 0.6
#: tan α is clamped here for the footprint of very wide lobes (tan → ∞ at 90°, notes §7.4).
MAX_FOOTPRINT_ANGLE = np.radians(85.0)
PATTERNS = ("ring", "line-b", "line-t")


def pattern(kind: str, n: int, radius: float = RING_RADIUS) -> np.ndarray:
    """The ``(n, 2)`` sample positions (ξ₁, ξ₂) of a pattern, exactly as in §4.4.3.

    ``ring``: (1, 0) then k = 1 … n−1 at (radius, (k−1)/(n−1)).
    ``line-b`` (m_x ≪ m_y): k ≤ ⌊n/2⌋ at ((2k+1)/n, 0.25), the rest at (2 − (2k+1)/n, 0.75);
    ξ₁ > 1 for even n means θ_h < 0, the mirror-symmetric position (not clamped).
    ``line-t`` (m_x ≫ m_y): the same with ξ₂ = 0 and 0.5.
    """
    if n < 1:
        raise ValueError(f"a sampling pattern needs at least one sample, got {n}")
    if kind == "ring":
        k = np.arange(1, n)
        return np.concatenate([[[1.0, 0.0]], np.stack([np.full(n - 1, radius), (k - 1) / max(n - 1, 1)], 1)])
    k = np.arange(n)
    first = k <= n // 2
    xi1 = np.where(first, (2 * k + 1) / n, 2 - (2 * k + 1) / n)
    a, b = (0.25, 0.75) if kind == "line-b" else (0.0, 0.5)
    return np.stack([xi1, np.where(first, a, b)], 1)


def choose_pattern(m_x: np.ndarray, m_y: np.ndarray, threshold: float) -> np.ndarray:
    """Per pixel 0 (ring), 1 (line-b: m_y/m_x > threshold) or 2 (line-t: m_x/m_y > threshold)."""
    r = m_y / m_x
    return np.where(r > threshold, 1, np.where(r < 1 / threshold, 2, 0))


# -- Beckmann lobes -------------------------------------------------------------------------------------------------


def beckmann_phi(xi2, m_x, m_y):
    """Eq 4.5/4.12 with the quadrant fix: φ_h = atan2(m_y sin 2πξ₂, m_x cos 2πξ₂)."""
    return np.arctan2(m_y * np.sin(2 * np.pi * xi2), m_x * np.cos(2 * np.pi * xi2))


def beckmann_a(phi, m_x, m_y):
    return np.cos(phi) ** 2 / m_x**2 + np.sin(phi) ** 2 / m_y**2


def theta_thresh(phi, m_x, m_y, xi_border=XI_BORDER):
    """Eq 4.10: the lobe cut θ_thresh(φ_h)."""
    return np.arctan(np.sqrt(-np.log(xi_border) / beckmann_a(phi, m_x, m_y)))


def half_vector(theta, phi):
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], -1)


def reflect(wo, h):
    """Eq 4.8: ω_i = 2(ω_o·h)h − ω_o."""
    return 2 * np.sum(wo * h, -1, keepdims=True) * h - wo


def beckmann_pdf(wi, wo, m_x, m_y):
    """Eq 4.9, the density of ω_i (solid angle) of the half-vector sampler, from the half vector of (ω_i, ω_o)."""
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    hz = h[..., 2]
    oh = np.sum(wo * h, -1)
    ok = (hz > 1e-9) & (oh > 0)
    hz_s = np.where(ok, hz, 1.0)
    e = (h[..., 0] ** 2 / m_x**2 + h[..., 1] ** 2 / m_y**2) / hz_s**2
    return np.where(ok, np.exp(-e) / (4 * np.pi * m_x * m_y * hz_s**3 * np.where(ok, oh, 1.0)), 0.0)


def beckmann_pdf_angles(theta, phi, oh, m_x, m_y):
    """Eq 4.9 from (θ_h, φ_h) and ω_o·h directly."""
    return np.exp(-np.tan(theta) ** 2 * beckmann_a(phi, m_x, m_y)) / (
        4 * np.pi * m_x * m_y * np.cos(theta) ** 3 * np.maximum(oh, 1e-300))


# -- cosine lobes ---------------------------------------------------------------------------------------------------


def axis_frame(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to unit axes ``a (..., 3)``, the same construction as the GLSL."""
    ref = np.where((np.abs(a[..., 2]) < 0.9)[..., None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    tu = np.cross(ref, a)
    tu /= np.linalg.norm(tu, axis=-1, keepdims=True)
    return tu, np.cross(a, tu)


def cosine_theta_thresh(n, xi_border=XI_BORDER):
    """The cut of the lobe cos^n θ that leaves out ξ_border of its importance-sampling mass."""
    return np.arccos(np.power(xi_border, 1.0 / (np.asarray(n, np.float64) + 1.0)))


def around(a, theta, phi):
    """Directions at angle θ from axes ``a (R, 3)``, azimuth φ in :func:`axis_frame`; θ, φ ``(R, K)``."""
    tu, tv = axis_frame(a)
    st = np.sin(theta)[..., None]
    return (st * (np.cos(phi)[..., None] * tu[:, None] + np.sin(phi)[..., None] * tv[:, None])
            + np.cos(theta)[..., None] * a[:, None])


# -- footprint and estimators ---------------------------------------------------------------------------------------


def footprint_lod(alpha_u, alpha_v, samples: int, dirs: np.ndarray, size: int) -> np.ndarray:
    """Eqs 4.14–4.17: the MIP level ``(R, K)`` of samples ``dirs (R, K, 3)`` (unit, world) on a cube of face ``size``.

    A = π tan α_U tan α_V at unit distance, A' = A / samples, projected onto
    the face (A'/cos³β for the cube [−1, 1]³), pixels = A'·S²/4, level = log₄ pixels.
    """
    u = np.tan(np.minimum(alpha_u, MAX_FOOTPRINT_ANGLE))
    v = np.tan(np.minimum(alpha_v, MAX_FOOTPRINT_ANGLE))
    area = (np.pi * u * v / samples)[..., None]
    cos_beta = np.abs(dirs).max(-1)
    pixels = area / np.maximum(cos_beta, 1e-6) ** 3 * size * size / 4
    return np.clip(0.5 * np.log2(np.maximum(pixels, 1e-30)), 0.0, np.log2(size))


def estimate(L, cos, f, p, valid, estimator: str = "4.25"):
    """The ratio estimators over the kept samples; ``L, f (R, K, 3)``, ``cos, p, valid (R, K)`` -> ``(R, 3)``.

    4.23: Σ L cos f / Σ p;  4.24: Σ L cos² f / Σ p cos;  4.25: Σ L cos² f²/p / Σ f cos (the thesis's choice).
    A pixel whose samples are all dropped gets 0.
    """
    w = valid.astype(np.float64)
    c = np.where(valid, cos, 0.0)
    ps = np.where(valid, p, 1.0)
    if estimator == "4.23":
        num, den = (L * f * c[..., None] * w[..., None]).sum(1), (p * w).sum(1)[:, None] * np.ones(3)
    elif estimator == "4.24":
        num, den = (L * f * (c**2)[..., None] * w[..., None]).sum(1), (p * c * w).sum(1)[:, None] * np.ones(3)
    elif estimator == "4.25":
        num = (L * f**2 / ps[..., None] * (c**2)[..., None] * w[..., None]).sum(1)
        den = (f * c[..., None] * w[..., None]).sum(1)
    else:
        raise ValueError(f"unknown estimator {estimator!r}; use 4.23, 4.24 or 4.25")
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


# -- Monte Carlo reference ------------------------------------------------------------------------------------------


def sobol_points(count: int, offset: int, seed: int, strategy: int) -> np.ndarray:
    """``count`` 2D scrambled Sobol points starting at ``offset`` (one sequence per strategy)."""
    import warnings

    from scipy.stats import qmc

    eng = qmc.Sobol(d=2, scramble=True, seed=seed * 7919 + strategy)
    if offset:
        eng.fast_forward(offset)
    with warnings.catch_warnings():  # any count is fine: blocks of a power of two are best balanced
        warnings.simplefilter("ignore", UserWarning)
        return eng.random(count)


def cosine_hemisphere(u):
    """Cosine-weighted directions in the surface frame, pdf cos θ / π."""
    r = np.sqrt(u[..., 0])
    phi = 2 * np.pi * u[..., 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1 - u[..., 0], 0.0))], -1)


def monte_carlo(model, params, wo, frame, incident, lobes: dict, samples: int, seed: int = 0, offset: int = 0,
                pixel_ids: np.ndarray | None = None, specular_only: bool = False) -> np.ndarray:
    """∫ L(ω_i) f_r(ω_i, ω_o) cos θ_i dω_i per pixel by MIS over cosine and lobe samplers, ``(R, 3)``.

    ``wo (R, 3)`` in the surface frame ``frame = (t, b, n)`` (world, each ``(R, 3)``); ``incident``:
    world directions ``(R, K, 3)`` -> radiance ``(R, K, 3)`` (an environment look-up, or ray casting);
    ``lobes``: ``{"cosine": [(axis_local (R,3), exponent (R,))...], "beckmann": [(m_x, m_y)...]}``;
    ``samples`` per strategy, points ``offset …`` of each strategy's sequence (progressive frames continue
    it); ``specular_only``: integrate f_r − ρ_d.
    """
    t, b, n = frame
    R = len(wo)
    strategies = [("cosine-hemisphere", None)] + [("cosine", lb) for lb in lobes.get("cosine", [])] + \
                 [("beckmann", lb) for lb in lobes.get("beckmann", [])]
    rng = np.random.default_rng(seed)
    ids = np.arange(R) if pixel_ids is None else pixel_ids
    # per-pixel Cranley-Patterson rotation, from a hash of the pixel id (independent of batching)
    rot = np.stack([(ids * 0.7548776662466927 + 0.5 + 0.1 * seed) % 1.0, (ids * 0.5698402909980532 + 0.5) % 1.0], 1)
    rot = (rot + rng.uniform(size=2)) % 1.0
    wis = []
    for j, (kind, lb) in enumerate(strategies):
        u = (sobol_points(samples, offset, seed, j)[None] + rot[:, None]) % 1.0  # (R, K, 2)
        u = np.clip(u, 1e-12, 1 - 1e-12)
        if kind == "cosine-hemisphere":
            wi = cosine_hemisphere(u)
        elif kind == "cosine":
            axis, e = lb
            theta = np.arccos(np.power(u[..., 0], 1.0 / (e[:, None] + 1.0)))
            wi = around(axis, theta, 2 * np.pi * u[..., 1])
        else:
            m_x, m_y = lb
            mx, my = m_x[:, None], m_y[:, None]
            phi = beckmann_phi(u[..., 1], mx, my)
            theta = np.arctan(np.sqrt(-np.log(1 - u[..., 0]) / beckmann_a(phi, mx, my)))
            wi = reflect(wo[:, None], half_vector(theta, phi))
        wis.append(wi)
    wi = np.concatenate(wis, 1)  # (R, J*K, 3)
    # balance heuristic over all strategies, each with `samples` points
    pdf = np.zeros(wi.shape[:2])
    for kind, lb in strategies:
        if kind == "cosine-hemisphere":
            pdf += np.maximum(wi[..., 2], 0) / np.pi
        elif kind == "cosine":
            axis, e = lb
            c = np.maximum(np.einsum("rkc,rc->rk", wi, axis), 0)
            pdf += (e[:, None] + 1) / (2 * np.pi) * np.power(c, e[:, None])
        else:
            pdf += beckmann_pdf(wi, wo[:, None], lb[0][:, None], lb[1][:, None])
    up = wi[..., 2] > 0
    f = model.eval(params, wi, np.broadcast_to(wo[:, None], wi.shape))
    if specular_only:
        f = f - np.asarray(params["rho_d"])[:, None]
    world = wi[..., :1] * t[:, None] + wi[..., 1:2] * b[:, None] + wi[..., 2:] * n[:, None]
    Li = incident(world)
    contrib = np.where((up & (pdf > 0))[..., None], f * Li * wi[..., 2:] / np.where(pdf > 0, pdf * samples, 1.0)[..., None], 0.0)
    return contrib.sum(1)
