"""What keeps a fitted texel physical and bounded where it was not measured.

A least-squares fit sees only the sampled direction pairs.  Between and
beyond them a lobe is free: a Lafortune lobe parked at n = 20000 with
|C_x| just above C_z is invisible at θ ≤ 75° and reaches 10²⁵ sr⁻¹ at
grazing, and a lobe narrower than the sampling can resolve can take any
height between two samples.  Those texels are the white specks of a render
and stretch every quantization range.  So each model declares, in
:meth:`BRDFModel.constrain <sbrdf_core.brdf.BRDFModel.constrain>`, how it
stays inside three bounds, all taken per texel from :class:`Limits`:

- **peak**: the largest f_r the lobes may reach anywhere on the hemisphere up
  to ``max_theta``, a stated factor times the largest value the texel's own
  valid samples and its 8 neighbours' show (:func:`sample_support`);
- **resolution**: the finest angular detail the samples resolve, from how
  close they come to the mirror configuration (:func:`angular_resolution`);
  exponents and roughness are bounded so a lobe's half width at half maximum
  is at least half of it;
- **albedo**: directional albedo ≤ ``albedo`` (energy conservation), checked
  by quadrature and enforced by scaling the ``magnitude`` parameters
  (:func:`enforce_energy`).

Fitters project onto the first two at every iteration (in the fit form); the
Fit node applies all three to whatever any fitter returns and flags the
texels it moved.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

from ._compiled import worth_compiling
from .brdf import evaluate
from .brdf_checks import energy_azimuths, energy_report, uncleared
from .channels import all_finite, channel_max
from .geometry import mirror_pairs
from .types import Limits

#: Samples counted when measuring how close the data comes to the mirror configuration.
NEAREST = 2
#: Incident elevations (degrees) where the energy bound is checked (those of brdf_checks.energy_report).
ENERGY_THETAS = (0.0, 30.0, 60.0, 75.0, 85.0)


def sample_support(f_r: np.ndarray, valid: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    """Largest valid sample value of each texel over poses and channels, ``(T,)`` (0 with none).

    ``weight`` ``(T, S)``, ≥ 0, multiplies each sample first (cos θ_i cos θ_o for :attr:`Limits.peak_cosine`).
    """
    # Channels first: one (T, S) array after this.  A non-finite channel counts as 0; the usual input (the Fit
    # node's, made usable) has none, and then the copy that zeroes them, a pass over the whole tile, is skipped.
    if all_finite(f_r).all():
        f = channel_max(f_r)
    else:
        with np.errstate(invalid="ignore"):
            f = channel_max(np.where(np.isfinite(f_r), f_r, 0.0))
    if weight is not None:
        f *= weight  # weights are ≥ 0, so the channels' maximum times the weight is the weighted maximum
    return np.where(valid, f, 0.0).max(axis=1, initial=0.0)


def neighbourhood_max(support: np.ndarray) -> np.ndarray:
    """3×3 maximum of a ``(V, U)`` map: a texel may be as bright as its neighbours show (edges clipped)."""
    from scipy.ndimage import maximum_filter

    return maximum_filter(np.asarray(support), size=3, mode="nearest")


def neighbourhood_min(resolution: np.ndarray) -> np.ndarray:
    """3×3 minimum of a ``(V, U)`` map: a texel may be as sharp as its neighbours' samples resolve.  Why: each
    texel's own training samples (a random held-out draw removed) resolve a slightly different angle, and a
    sharpness bound that follows those draws widens random texels of one material: specks."""
    from scipy.ndimage import minimum_filter

    return minimum_filter(np.asarray(resolution), size=3, mode="nearest")


def angular_resolution(wi: np.ndarray, wo: np.ndarray, valid: np.ndarray, nearest: int = NEAREST) -> np.ndarray:
    """How close each texel's samples come to the mirror configuration, radians, ``(T,)``.

    The ``nearest``-th smallest angle between ω_o and the mirror direction of
    ω_i over the valid samples: a specular lobe narrower than this has no
    sample on its flanks, so its width and height are not measured.  π/2 for
    a texel with fewer valid samples.
    """
    # The k-th smallest angle is the arccos of the k-th largest cosine (arccos falls monotonically): one arccos per
    # texel, not per sample.  An invalid sample's cosine 0 is the angle π/2 it stood for.
    negated = _negated_mirror_cosines(np.asarray(wi), np.asarray(wo), np.asarray(valid, bool))
    k = min(nearest, negated.shape[1]) - 1
    if k < 0:
        return np.full(negated.shape[0], np.pi / 2)
    largest = -np.partition(negated, k, axis=1)[:, k]
    return np.minimum(np.arccos(largest), np.pi / 2)


def _negated_mirror_cosines(wi: np.ndarray, wo: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """−cos of each sample's angle between ω_o and ω_i's mirror direction, clipped to [−1, 1], −0 where invalid,
    ``(T, S)``: what :func:`angular_resolution` partitions."""
    if (worth_compiling(valid.size) and wi.ndim == 3 and wi.shape == wo.shape and wi.shape[-1] == 3
            and wi.dtype == wo.dtype == np.float64 and valid.shape == wi.shape[:2]):
        # One pass instead of NumPy's seven over strided channels, the same bits
        # (tests/plugins/test_bounded_fits.py).
        return _compiled_negated_cosines()(wi, wo, valid)
    cos_a = wi[..., 2] * wo[..., 2] - wi[..., 0] * wo[..., 0] - wi[..., 1] * wo[..., 1]
    return -np.where(valid, np.clip(cos_a, -1.0, 1.0), 0.0)


@functools.cache
def _compiled_negated_cosines():
    """:func:`_negated_mirror_cosines`' kernel (numba, cached on disk)."""
    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(wi, wo, valid):  # pragma: no cover (compiled)
        T, S = valid.shape
        out = np.empty((T, S))
        for t in range(T):
            for s in range(S):
                c = wi[t, s, 2] * wo[t, s, 2] - wi[t, s, 0] * wo[t, s, 0] - wi[t, s, 1] * wo[t, s, 1]
                c = -1.0 if c < -1.0 else (1.0 if c > 1.0 else c)  # np.clip's; NaN passes
                out[t, s] = -c if valid[t, s] else -0.0
        return out

    return kernel


def clip_shape(params, names, low=None, high=None) -> tuple[dict, np.ndarray]:
    """Clip the named shape parameters to per-texel ``(T, 1)`` bounds; returns ``(params, changed)``."""
    out = dict(params)
    changed = np.zeros(next(iter(out.values())).shape[0], bool)
    for name in names:
        v = np.asarray(out[name], np.float64)
        c = v if low is None else np.maximum(v, low)
        c = c if high is None else np.minimum(c, high)
        changed |= (c != v).any(axis=-1)
        out[name] = c
    return out, changed


def mirror_peak(model, params, max_theta, n: int = 24, cosine: bool = False) -> np.ndarray:
    """Largest f_r over mirror pairs with θ ≤ ``max_theta`` (radians), in two azimuths, ``(T,)``.

    Where a microfacet or Phong-like lobe peaks.  ``cosine``: of f_r·cos²θ
    instead, which divides out the 1/(4 cos θ_i cos θ_o) growth toward grazing.
    """
    T = next(iter(params.values())).shape[0]
    d, m = mirror_pairs(max_theta, n)
    with np.errstate(all="ignore"):
        f = evaluate(model, params, np.broadcast_to(d, (T,) + d.shape), np.broadcast_to(m, (T,) + m.shape))
    if cosine:
        f = f * (d[:, 2] ** 2)[None, :, None]
    return np.where(np.isfinite(f), f, np.inf).max(axis=(1, 2))


def widen_to_peak(model, params, names, limits: Limits, steps: int = 16, tolerance: float = 1e-4,
                  ) -> tuple[dict, np.ndarray]:
    """Raise the roughness parameters ``names`` (one common factor) until the lobe's peak fits the limits.

    For models whose peak is set by a width rather than a magnitude
    (Cook–Torrance: F → 1 at grazing whatever F0): a wider lobe keeps its
    energy and loses height.  The peak compared is that of f_r·cos θ_i·cos θ_o
    against ``limits.peak_cosine`` where given: a microfacet lobe's growth
    toward grazing (1/cos², Fresnel) is the model's physics, and bounding it
    by the samples' largest f_r would bend the fit where it was measured.

    The factor is searched in log space up to each parameter's upper bound by
    regula falsi on the log of the peak (Illinois variant), which is nearly
    linear in the log of the roughness (a GGX lobe's peak goes as α⁻²): a
    texel settles in a few evaluations where bisection took ``steps``.  It
    stops within ``tolerance`` (relative) below the bound, always on the side
    that fits; a texel still over at the widest keeps the widest lobe.
    """
    out = dict(params)
    T = next(iter(out.values())).shape[0]
    cosine = limits.peak_cosine is not None
    bound = limits.peak_cosine if cosine else limits.peak
    if bound is None:
        return out, np.zeros(T, bool)
    bound = np.asarray(bound, np.float64)
    peak = mirror_peak(model, out, limits.max_theta, cosine=cosine)
    over = np.flatnonzero(peak > bound * (1 + 1e-6))
    if over.size == 0:
        return out, np.zeros(T, bool)
    caps = {p.name: p.bounds[1] for p in model.parameters}
    sub = {k: np.asarray(v, np.float64)[over] for k, v in out.items()}
    target = np.log(bound[over])

    def excess(rows, factor):  # log(peak / bound) of texels ``rows`` of ``over`` widened by exp(factor)
        trial = {k: v[rows] for k, v in sub.items()}
        trial.update({n: np.minimum(sub[n][rows] * np.exp(factor)[:, None], caps[n]) for n in names})
        with np.errstate(divide="ignore"):
            return np.log(mirror_peak(model, trial, limits.max_theta, cosine=cosine)) - target[rows]

    room = np.max([np.log(caps[n] / np.maximum(sub[n][:, 0], 1e-300)) for n in names], axis=0)
    lo, hi = np.zeros(over.size), np.maximum(room, 0.0)  # log of the factor: lo fails, hi is the widest allowed
    with np.errstate(divide="ignore"):
        g_lo = np.log(peak[over]) - target
    g_hi = excess(np.arange(over.size), hi)
    active = np.flatnonzero((g_hi < -tolerance) & np.isfinite(g_hi))
    side = np.zeros(over.size, np.int8)  # which end moved last: Illinois halves the other end's value
    for _ in range(steps):
        if active.size == 0:
            break
        a, b = lo[active], hi[active]
        ga, gb = g_lo[active], g_hi[active]
        with np.errstate(invalid="ignore"):  # an infinite peak at ``lo``: bisect
            mid = np.where(np.isfinite(ga), a + (b - a) * ga / (ga - gb), 0.5 * (a + b))
        mid = np.clip(mid, a + 1e-3 * (b - a), b - 1e-3 * (b - a))
        g = excess(active, mid)
        g = np.where(np.isnan(g), np.inf, g)  # no finite peak: treated as over
        fits = g <= 0
        hi[active], g_hi[active] = np.where(fits, mid, b), np.where(fits, g, gb)
        lo[active], g_lo[active] = np.where(fits, a, mid), np.where(fits, ga, g)
        # Illinois: an end that stays twice in a row has its value halved, so regula falsi cannot stall there
        stay_lo, stay_hi = fits & (side[active] == 1), ~fits & (side[active] == -1)
        g_lo[active[stay_lo]] *= 0.5
        g_hi[active[stay_hi]] *= 0.5
        side[active] = np.where(fits, 1, -1)
        done = (fits & (g > -tolerance)) | (hi[active] - lo[active] < 1e-9)
        active = active[~done]
    for n in names:
        v = np.array(out[n], np.float64)
        v[over] = np.minimum(sub[n] * np.exp(hi)[:, None], caps[n])
        out[n] = v
    changed = np.zeros(T, bool)
    changed[over] = hi > 1e-9  # a texel already at its widest does not move
    return out, changed


class WidenedRoughness:
    """Bounds of a microfacet (or Ward) model, mixed in before :class:`~sbrdf_core.brdf.BRDFModel`: the declared
    bounds and ρ_d ≤ peak, the ``roughness`` parameters no narrower than the sampling resolves, and wide enough
    that the mirror peak (where F → 1 and 1/cos² grows) stays within the limits (:func:`widen_to_peak`).  Nothing
    else, so the fitting engine holds all of it inside its loop (``widens_to_peak``)."""

    widens_to_peak = True

    def constrain(self, params, limits):
        """Compiled (:func:`~sbrdf_core.engine.project`) for the texels with finite parameters where the model
        has a fit kernel; the rest, and models without one, by NumPy (:func:`widen_to_peak`, the reference)."""
        from .engine import project

        form = self.fit_form()  # type: ignore[attr-defined]
        T = next(iter(params.values())).shape[0]
        x = form.pack(form.from_model(params))
        ok = np.flatnonzero(np.isfinite(x).all(axis=1))
        moved = project(form, x[ok], limits.take(ok)) if ok.size else None
        if moved is None:
            return self._constrain_numpy(params, limits)
        changed = np.zeros(T, bool)
        out = {k: np.array(v, np.float64) for k, v in params.items()}
        rest = np.setdiff1d(np.arange(T), ok)
        if rest.size:
            sub, changed[rest] = self._constrain_numpy({k: v[rest] for k, v in out.items()}, limits.take(rest))
            for k in out:
                out[k][rest] = sub[k]
        new = {k: np.asarray(v, np.float64) for k, v in form.to_model(form.unpack(moved)).items()}
        differs = np.zeros(ok.size, bool)  # judged in the model's own parameters: from_model clipped them
        for k, v in new.items():
            old = out[k][ok]
            differs |= (np.abs(v - old) > 1e-9 * (1.0 + np.abs(old))).reshape(ok.size, -1).any(axis=1)
        rows = ok[differs]
        changed[rows] = True
        for k, v in new.items():
            out[k][rows] = v[differs]
        return out, changed

    def _constrain_numpy(self, params, limits):
        out, changed = super().constrain(params, limits)  # type: ignore[misc]
        out, finer = clip_shape(out, self.roughness, low=limits.min_roughness())  # type: ignore[attr-defined]
        out, wider = widen_to_peak(self, out, self.roughness, limits)  # type: ignore[attr-defined]
        return out, changed | finer | wider


def enforce_energy(model, params, albedo: float | None, n_theta: int = 24, n_phi: int = 48,
                   cleared: set | None = None):
    """Scale each texel's ``magnitude`` parameters so its directional albedo stays ≤ ``albedo``.

    Albedo by :func:`~sbrdf_core.brdf_checks.energy_report` at
    :data:`ENERGY_THETAS` (and three azimuths for anisotropic models), on a
    coarse grid: exact for the diffuse term and smooth lobes, approximate for
    lobes sharper than the grid (whose albedo is small once their peak is
    bounded).  Texels the model's :meth:`~sbrdf_core.brdf.BRDFModel.albedo_bound`
    already clears are not integrated, nor those whose parameters are in ``cleared``: a set of packed rows
    (as bytes) this bound already returned for the same ``albedo``, to which the rows it returns are added.
    Why: the bound depends on the parameters alone, not the texel, and a Fit tile checks many a solution
    more than once (a neighbour's, taken; then the tile's result).  Returns ``(params, changed)``.
    """
    T = next(iter(params.values())).shape[0]
    out = {k: np.array(v, np.float64) for k, v in params.items()}
    changed = np.zeros(T, bool)
    mags = [p.name for p in model.parameters if p.magnitude]
    if albedo is None or not mags or T == 0:
        return out, changed
    phis = energy_azimuths(model)
    todo = uncleared(model, out, albedo)  # texels the analytic bound clears need no quadrature
    if cleared is not None:
        todo = todo[[row.tobytes() not in cleared for row in model.pack(out)[todo]]].astype(np.intp)
    for _ in range(6):  # F0 is affine, not linear: later passes (on the texels still over) catch what is left
        if todo.size == 0:
            break
        sub = {k: v[todo] for k, v in out.items()}
        with np.errstate(all="ignore"):
            a = energy_report(model, sub, np.radians(ENERGY_THETAS), phis, n_theta, n_phi).max_albedo
        over = np.isfinite(a) & (a > albedo * (1.0 + 1e-4))
        if not over.any():
            break
        todo, a = todo[over], a[over]
        for name in mags:
            out[name][todo] = out[name][todo] * (albedo / a)[:, None]
        changed[todo] = True
    if cleared is not None:
        cleared.update(row.tobytes() for row in model.pack(out))
    return out, changed


#: Bits of the Fit node's ``bounded_by`` map: which bound moved a texel.
REASONS = {1: "peak (peak_factor, grazing_growth) or the declared parameter bounds",
           2: "sharpness the sampling resolves (resolve_sharpness)",
           4: "energy: directional albedo (albedo_limit)"}
PEAK, SHARPNESS, ENERGY = 1, 2, 4


def reasons(model, params, limits: Limits, energy: np.ndarray) -> np.ndarray:
    """Which bounds moved each texel of ``params`` (the unprojected fit), ``(T,)`` uint8 of :data:`REASONS`.

    Each bound is projected alone, so a texel held by two of them shows both.
    ``energy`` is the mask :func:`enforce_energy` returned.
    """
    _, peak = model.constrain(params, replace(limits, resolution=None))
    _, sharp = model.constrain(params, replace(limits, peak=None, peak_cosine=None, growth=None))
    T = next(iter(params.values())).shape[0]
    out = np.zeros(T, np.uint8)
    for mask, bit in ((peak, PEAK), (sharp, SHARPNESS), (energy, ENERGY)):
        if np.size(mask):
            out |= np.where(mask, bit, 0).astype(np.uint8)
    return out


def enforce(model, params, limits: Limits, why: bool = False, cleared: set | None = None):
    """All three bounds on model-form ``params``: ``model.constrain`` then the energy bound.

    Returns ``(params, changed)``, and with ``why`` a third item: the
    :func:`reasons` of each moved texel (0 elsewhere).  What every fitted
    texel goes through in the Fit node, whatever fitter produced it.
    ``cleared``: :func:`enforce_energy`'s, shared by calls with the same ``limits.albedo``.
    """
    out, changed = model.constrain(params, limits)
    if changed.size == 0:
        changed = np.zeros(next(iter(out.values())).shape[0], bool)
    out, energy = enforce_energy(model, out, limits.albedo, cleared=cleared)
    changed = changed | energy
    if not why:
        return out, changed
    moved = np.flatnonzero(changed)
    bits = np.zeros(changed.shape, np.uint8)
    if moved.size:
        sub = {k: np.asarray(v)[moved] for k, v in params.items()}
        bits[moved] = reasons(model, sub, limits.take(moved), energy[moved])
    return out, changed, bits
