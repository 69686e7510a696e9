"""Physical-plausibility checks that work on any BRDF-model plugin.

A fitted or hand-made SBRDF is not guaranteed to be reciprocal or energy
conserving (Lafortune lobes with |C| > 1 or a large ρ_s are neither bounded
nor normalised, seed 000 notes §20 item 14), and renderers that integrate
lighting (environment prefiltering, path tracing) misbehave on texels that
reflect more than they receive.  These checks say which texels those are.
They use only :meth:`BRDFModel.eval`, vectorised over texels.

- :func:`reciprocity_error`: max relative |f(ω_i, ω_o) − f(ω_o, ω_i)| over random pairs.
- :func:`directional_albedo`: a(ω_i) = ∫ f(ω_i, ω_o) cos θ_o dω_o by deterministic quadrature.
- :func:`energy_report`: the largest albedo over a set of incident directions, and the texels above 1.
- :func:`energy_violations`: the texels neither the model's analytic albedo bound nor the quadrature clears.
- :func:`hemisphere_max`: the largest f_r over the hemisphere where lobes peak (fireflies).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .brdf import BRDFModel, evaluate
from .contracts import optional
from .geometry import polar_direction

#: Upper bound on texels × directions evaluated at once (memory: ~10 float64 temporaries of (T, S, 3)).
CHUNK = 1 << 18


def hemisphere_directions(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Directions uniform in solid angle over the upper hemisphere, ``shape + (3,)``, grazing included."""
    z = 1.0 - rng.random(shape)  # (0, 1]
    phi = rng.uniform(0.0, 2 * np.pi, shape)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def reciprocity_error(model: BRDFModel, params: Mapping[str, np.ndarray], n_pairs: int = 256,
                      rng: np.random.Generator | None = None) -> np.ndarray:
    """Per texel, ``max |f(ω_i, ω_o) − f(ω_o, ω_i)| / max(|f(ω_i, ω_o)|, |f(ω_o, ω_i)|)``, ``(T,)``.

    Over ``n_pairs`` random direction pairs per texel (uniform on the upper
    hemisphere, so grazing pairs occur) and the three channels; pairs where
    both values are 0 count as exact.  A reciprocal model gives ~1e-15.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    T = _texels(model, params)
    wi = hemisphere_directions(rng, (T, n_pairs))
    wo = hemisphere_directions(rng, (T, n_pairs))
    a, b = model.eval(params, wi, wo), model.eval(params, wo, wi)
    scale = np.maximum(np.abs(a), np.abs(b))
    rel = np.abs(a - b) / np.where(scale > 0, scale, 1.0)
    return rel.max(axis=(1, 2))


def quadrature(n_theta: int = 64, n_phi: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """Outgoing directions ``(n_theta · n_phi, 3)`` and weights with Σ w g(ω) ≈ ∫ g(ω) cos θ dω over the hemisphere.

    Gauss–Legendre in μ = cos θ on [0, 1] (exact for polynomials in μ of degree
    2 n_theta − 1, dense near the pole and the horizon) times the midpoint rule
    in φ (spectrally accurate for periodic integrands); dω = dμ dφ and the
    cos θ factor is folded into the weights.  Cached: treat the arrays as read-only.
    """
    return _quadrature(int(n_theta), int(n_phi))


@lru_cache(maxsize=16)
def _quadrature(n_theta: int, n_phi: int) -> tuple[np.ndarray, np.ndarray]:
    from scipy.special import roots_legendre  # O(n²) nodes; numpy's leggauss is a dense O(n³) eigenproblem

    x, w = roots_legendre(n_theta)
    mu, w_mu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    s = np.sqrt(1.0 - mu * mu)
    dirs = np.stack([np.outer(s, np.cos(phi)), np.outer(s, np.sin(phi)), np.repeat(mu[:, None], n_phi, axis=1)], axis=-1)
    weights = np.repeat((w_mu * mu)[:, None], n_phi, axis=1) * (2 * np.pi / n_phi)
    dirs, weights = dirs.reshape(-1, 3), weights.reshape(-1)
    dirs.flags.writeable = weights.flags.writeable = False
    return dirs, weights


def directional_albedo(model: BRDFModel, params: Mapping[str, np.ndarray], wi: np.ndarray,
                       n_theta: int = 64, n_phi: int = 128, mirror: bool = False) -> np.ndarray:
    """Directional albedo a(ω_i) = ∫ f_r(ω_i, ω_o) cos θ_o dω_o per texel and channel, ``(T, 3)``.

    ``wi`` is one direction ``(3,)`` for every texel or one per texel ``(T, 3)``.
    Quadrature: :func:`quadrature` (Gauss–Legendre in cos θ_o × midpoint in φ_o),
    deterministic, so a check gives the same answer every run.  The default
    64 × 128 grid integrates a Lambertian term exactly, a normal-incidence
    cosine lobe cos^n exactly up to n ≈ 125, and smooth lobes to ~1e-6.
    Sharp lobes need more points: a lobe cos^n α has angular width ≈ 1/√n, and
    the grid spacing near the lobe (≈ π/n_theta in θ away from the pole,
    2π/n_phi · sin θ in φ) must be several times smaller — for n ≈ 10⁴, or a
    Ward/Cook–Torrance α ≈ 0.01, use n_theta ≈ 512 and n_phi ≈ 1024 (cost grows
    as T × n_theta × n_phi evaluations).

    ``mirror``: the integrand is symmetric under φ_o → −φ_o (an isotropic
    model, ω_i in the xz-plane), so half the φ grid with doubled weights gives
    the same sum (its midpoints pair up across the plane: n_phi even); half the work.
    The grid is summed by the model's fit kernel where it has one (:func:`~sbrdf_core.engine.integrate`), else
    evaluated by ``model.eval`` in chunks.
    """
    T = _texels(model, params)
    wi = np.broadcast_to(np.asarray(wi, dtype=np.float64), (T, 3))
    dirs, weights = quadrature(n_theta, n_phi)
    if mirror and n_phi % 2 == 0:
        half = (np.arange(n_theta * n_phi) % n_phi) < n_phi // 2  # φ in (0, π): rows are θ, n_phi φ each
        dirs, weights = dirs[half], 2.0 * weights[half]
    from .engine import integrate

    with np.errstate(all="ignore"):
        summed = integrate(model, params, wi, dirs, weights)
    if summed is not None:
        return summed
    out = np.zeros((T, 3))
    step = max(1, CHUNK // max(T, 1))
    for start in range(0, len(dirs), step):
        wo = np.broadcast_to(dirs[start:start + step], (T,) + dirs[start:start + step].shape)
        wi_s = np.broadcast_to(wi[:, None, :], wo.shape)
        out += np.einsum("tsc,s->tc", evaluate(model, params, wi_s, wo), weights[start:start + step])
    return out


@dataclass(frozen=True)
class EnergyReport:
    """Result of :func:`energy_report`.

    Attributes
    ----------
    directions
        The incident directions checked, ``(D, 3)``.
    albedo
        Directional albedo per texel, direction and channel, ``(T, D, 3)``.
    max_albedo
        Largest albedo of each texel over directions and channels, ``(T,)``.
    worst_direction
        The incident direction where it occurs, ``(T, 3)``.
    violations
        Mask ``(T,)`` of texels with ``max_albedo > limit + tolerance``.
    limit
        The bound checked (1: a surface reflects at most what it receives).
    """

    directions: np.ndarray
    albedo: np.ndarray
    max_albedo: np.ndarray
    worst_direction: np.ndarray
    violations: np.ndarray
    limit: float

    @property
    def violating_texels(self) -> np.ndarray:
        """Flat indices of the texels that violate the bound."""
        return np.flatnonzero(self.violations)

    @property
    def ok(self) -> bool:
        return not bool(self.violations.any())

    def summary(self) -> str:
        n, T = int(self.violations.sum()), self.violations.size
        worst = float(self.max_albedo.max()) if T else 0.0
        return f"{n} of {T} texels reflect more than {self.limit:g} of the incident energy (max albedo {worst:.4g})"


def energy_report(model: BRDFModel, params: Mapping[str, np.ndarray],
                  incident_thetas: Sequence[float] | np.ndarray = tuple(np.radians([0.0, 30.0, 60.0, 75.0, 85.0])),
                  incident_phis: Sequence[float] | np.ndarray = (0.0, np.pi / 4, np.pi / 2),
                  n_theta: int = 64, n_phi: int = 128, limit: float = 1.0, tolerance: float = 1e-3) -> EnergyReport:
    """Directional albedo at every ``(θ_i, φ_i)`` combination (radians) and the texels exceeding ``limit``.

    The energy bound (seed 000 Eq 2.8) must hold for every ω_i; a few
    elevations (most violations appear toward grazing) and azimuths (for
    anisotropic lobes) stand in for all of them.  A texel violates the bound
    when its albedo exceeds ``limit + tolerance``: the tolerance absorbs the
    quadrature error of a model that reflects exactly everything (a smooth
    F0 = 1 microfacet surface).  That error can have either sign and grows
    for sharp lobes and grazing incidence: raise ``n_theta`` / ``n_phi`` (see
    :func:`directional_albedo`) before trusting a result near the limit.
    """
    th = np.asarray(incident_thetas, dtype=np.float64)
    ph = np.asarray(incident_phis, dtype=np.float64)
    th, ph = np.meshgrid(th, ph, indexing="ij")
    dirs = polar_direction(th.ravel(), ph.ravel())
    # At θ_i = 0 every φ_i is one direction: integrated once
    once, first = np.unique(dirs, axis=0, return_inverse=True)
    first = np.asarray(first).reshape(-1)
    # An isotropic model's albedo at φ_i = 0 is symmetric in φ_o: half the grid (directional_albedo's mirror).
    mirror = (once[:, 1] == 0.0) & (not optional(model, "anisotropic", "brdf-model"))
    parts = [(pick, _albedo_at(model, params, once[pick], m, n_theta, n_phi))
             for m in (False, True) if (pick := np.flatnonzero(mirror == m)).size]
    unique = np.empty((_texels(model, params), len(once), parts[0][1].shape[-1]))  # the model's channels
    for pick, part in parts:
        unique[:, pick] = part
    albedo = unique[:, first]
    per_dir = albedo.max(axis=2)  # (T, D)
    worst = per_dir.argmax(axis=1)
    max_albedo = per_dir.max(axis=1)
    return EnergyReport(directions=dirs, albedo=albedo, max_albedo=max_albedo, worst_direction=dirs[worst],
                        violations=max_albedo > limit + tolerance, limit=float(limit))


def _albedo_at(model: BRDFModel, params: Mapping[str, np.ndarray], dirs: np.ndarray, mirror: bool, n_theta: int,
               n_phi: int) -> np.ndarray:
    """:func:`directional_albedo` at each of ``dirs`` ``(D, 3)``, ``(T, D, 3)``; for a model with a fit kernel, in
    one call, the texels repeated per direction (the same sums): the compiled evaluation then gets batches big
    enough to pay for it.  A model evaluated with ``eval`` gains nothing (its cost is per evaluation) and keeps a
    call per direction, whose chunks of the grid, and so its sums' order, do not depend on D."""
    if getattr(model.fit_form(), "kernel", None) is None:
        return np.stack([directional_albedo(model, params, d, n_theta, n_phi, mirror) for d in dirs], axis=1)
    T, D = _texels(model, params), len(dirs)
    rows = {k: np.concatenate([np.broadcast_to(np.asarray(v), (T,) + np.shape(v)[1:])] * D) for k, v in params.items()}
    out = directional_albedo(model, rows, np.repeat(dirs, T, axis=0), n_theta, n_phi, mirror)
    return out.reshape(D, T, out.shape[-1]).transpose(1, 0, 2)  # not -1: T may be 0


def energy_azimuths(model: BRDFModel) -> tuple[float, ...]:
    """Incident azimuths (radians) the energy bound is checked and enforced at: one for an isotropic model (its
    albedo does not depend on φ_i), three for an anisotropic one."""
    return (0.0, np.pi / 4, np.pi / 2) if optional(model, "anisotropic", "brdf-model") else (0.0,)


def uncleared(model: BRDFModel, params: Mapping[str, np.ndarray], limit: float) -> np.ndarray:
    """Indices of the texels the model's analytic ``albedo_bound`` does not hold within ``limit``: those to integrate."""
    bound = model.albedo_bound(params)
    return np.arange(_texels(model, params)) if bound is None else np.flatnonzero(~(np.asarray(bound) <= limit))


def energy_violations(model: BRDFModel, params: Mapping[str, np.ndarray], limit: float = 1.0,
                      tolerance: float = 2e-3, n_theta: int = 24, n_phi: int = 48) -> np.ndarray:
    """Texels whose directional albedo may exceed ``limit``, ``(T,)`` bool: the energy bound as the Fit node holds it.

    A texel is cleared by the model's analytic :meth:`~sbrdf_core.brdf.BRDFModel.albedo_bound`
    (an upper bound, exact whatever the lobe's sharpness) or, where that does
    not clear it, by :func:`energy_report` on the same grid
    :func:`~sbrdf_core.constraints.enforce_energy` enforces it on.  Why both:
    a Lafortune lobe of n ≈ 1400 is 2.6° wide, narrower than a coarse grid's
    spacing, whose quadrature then reads 1.007 for a lobe the bound proves at
    0.998; checking the quadrature alone fails texels that conserve energy.
    """
    T = _texels(model, params)
    todo = uncleared(model, params, limit)
    out = np.zeros(T, bool)
    if todo.size:
        sub = {k: np.asarray(v)[todo] for k, v in params.items()}
        with np.errstate(all="ignore"):
            a = energy_report(model, sub, incident_phis=energy_azimuths(model), n_theta=n_theta,
                              n_phi=n_phi).max_albedo
        out[todo] = ~(a <= limit + tolerance)
    return out


def _texels(model: BRDFModel, params: Mapping[str, np.ndarray]) -> int:
    first = model.parameters[0].name if model.parameters else next(iter(params))
    return int(np.asarray(params[first]).shape[0])


def hemisphere_max(model: BRDFModel, params: Mapping[str, np.ndarray], max_theta_deg: float = 89.0,
                   n_theta: int = 46, n_phi: int = 36, chunk: int = 256) -> np.ndarray:
    """Largest f_r of each texel over direction pairs up to ``max_theta_deg``, ``(T,)`` (any channel).

    Where lobes peak: mirror pairs, retro-reflection pairs, and ω_o mirrored
    in one tangent axis only (anisotropic lobes), for every ω_i of a
    θ × φ grid, plus the grid's cross pairs at equal θ.  A deterministic
    lower bound on the true maximum that catches fireflies (a lobe that
    explodes toward grazing or at the mirror direction) at a fraction of a
    dense 4D search.
    """
    th = np.radians(np.linspace(0.0, max_theta_deg, n_theta))
    ph = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False)
    d = polar_direction(*np.meshgrid(th, ph, indexing="ij")).reshape(-1, 3)
    swap = d[:, [1, 0, 2]] * [-1, 1, 1]  # the same θ, φ + 90°
    wi = np.concatenate([d, d, d, d, d])
    wo = np.concatenate([d * [-1, -1, 1], d, d * [-1, 1, 1], d * [1, -1, 1], swap])
    T = _texels(model, params)
    out = np.zeros(T)
    for s in range(0, T, chunk):
        sl = slice(s, min(s + chunk, T))
        n = sl.stop - sl.start
        sub = {k: np.asarray(v)[sl] for k, v in params.items()}
        with np.errstate(all="ignore"):
            f = model.eval(sub, np.broadcast_to(wi, (n,) + wi.shape), np.broadcast_to(wo, (n,) + wo.shape))
        out[sl] = np.where(np.isfinite(f), f, np.inf).max(axis=(1, 2))
    return out
