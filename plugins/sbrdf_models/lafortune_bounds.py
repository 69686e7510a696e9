"""lafortune_bounds: the physical bounds of Lafortune lobes (the peak budget, the resolvable exponent, dead lobes).

Shared by the model form (:meth:`~sbrdf_models.lafortune.LafortuneModel.constrain`) and the fit form
(:meth:`~sbrdf_models.lafortune_fit.LafortuneFitForm.constrain`), in the C_z = 1 gauge; the compiled projection
is :mod:`.lafortune_kernels`, the GLSL one ``LafortuneModel.glsl_fit_constrain``.
"""

from __future__ import annotations

import numpy as np

#: McAllister's initial guesses (§4.3.1): lobe 1 forward (mirror), lobe 2 back-scatter.
INITIAL_LOBES = ((-1.0, -1.0, 1.0, 10.0), (1.0, 1.0, 1.0, 5.0))
EXPONENT_BOUNDS = (0.1, 20000.0)
#: A lobe whose peak is below this fraction of the texel's peak budget and of its ρ_d contributes nothing visible.
NEGLIGIBLE = 1e-3
#: The neutral shape a dead lobe is reset to: a mirror cosine lobe, n = 1 (bounded under interpolation).
NEUTRAL_EXPONENT = 1.0


def bound_lobes(rho_d, lobes, limits):
    """Scale factors that keep C_z = 1 lobes bounded: ``[(rho_scale, c_scale, exponent, dead)], changed``.

    ``lobes`` is ``[(rho_s (T, C), |C|_max (T, 1), n (T, 1))]``.  Each lobe
    gets n ≤ the sharpest the sampling resolves and a shape that grows toward
    grazing by at most ``limits.growth`` (m^n, whatever ρ_s); then, against a
    budget of ``limits.peak − max ρ_d``: ρ_s scaled down if it alone exceeds
    it, |C| shrunk toward 1 until ρ_s·m^n fits (the grazing growth is what the
    samples did not see), and all ρ_s scaled together if the lobes' peaks add
    up to more.  A lobe left below :data:`NEGLIGIBLE` of the budget and of the
    diffuse term is ``dead``: callers reset it to a neutral shape, because an invisible lobe
    parked at |C| = 10 or n = 0.1 turns into a real one when a renderer
    interpolates it with its neighbour's.
    """
    T = rho_d.shape[0]
    changed = np.zeros(T, bool)
    s2, c2 = np.sin(limits.max_theta) ** 2, np.cos(limits.max_theta) ** 2
    n_cap = limits.max_cosine_exponent()
    if limits.peak is None:
        budget = np.full((T, 1), np.inf)
    else:
        budget = np.maximum(np.asarray(limits.peak, np.float64)[:, None] - rho_d.max(axis=1, keepdims=True), 0.0)
    out, peaks = [], []
    with np.errstate(all="ignore"):
        for rho, cabs, n in lobes:
            n_new = np.clip(np.minimum(n, n_cap), *EXPONENT_BOUNDS)
            rmax = rho.max(axis=1, keepdims=True)
            r_scale = np.where(rmax > budget, budget / np.where(rmax > 0, rmax, 1.0), 1.0)
            r = rmax * r_scale
            log_m = np.where((r > 0) & np.isfinite(budget), np.log(budget / np.where(r > 0, r, 1.0)) / n_new, np.inf)
            if limits.growth is not None:
                log_m = np.minimum(log_m, np.log(max(limits.growth, 1.0)) / n_new)
            m_allowed = np.exp(np.minimum(log_m, 50.0))
            c_allowed = np.maximum((m_allowed - c2) / s2, 1.0)
            c_scale = np.where(cabs > c_allowed, c_allowed / np.where(cabs > 0, cabs, 1.0), 1.0)
            m = np.maximum(1.0, cabs * c_scale * s2 + c2)
            peaks.append(r * np.exp(np.minimum(n_new * np.log(m), 700.0)))
            out.append([r_scale, c_scale, n_new])
            changed |= ((n_new < n * (1 - 1e-9)) | (r_scale < 1 - 1e-9) | (c_scale < 1 - 1e-9))[:, 0]
        total = np.sum(peaks, axis=0)
        share = np.where(total > budget, budget / np.where(total > 0, total, 1.0), 1.0)
    changed |= share[:, 0] < 1 - 1e-9
    # Dead: negligible against the budget *and* against the diffuse term.  Why both: a broad weak lobe under a
    # sharp one (peak 0.06 against a budget of 60) is far below the budget yet carries a twentieth of the albedo.
    floor = NEGLIGIBLE * np.minimum(budget, rho_d.max(axis=1, keepdims=True))
    for lobe, peak in zip(out, peaks):
        lobe[0] = lobe[0] * share
        lobe.append(((peak * share) < floor) & np.isfinite(budget))
    return out, changed


def _apply_lobe_bounds(model, out, limits, exponent_key, log, reset_dead=True):
    """:func:`bound_lobes` on ``out`` in place (model form or fit form, C_z = 1); returns ``changed``.

    ``reset_dead`` (model form only) neutralises dead lobes; the fit form
    keeps them as they are: a lobe the iteration is about to grow starts small.
    """
    names = ("c_x", "c_y") if model.anisotropic else ("c_xy",)
    lobes = []
    for j in range(1, model.lobes + 1):
        n = np.asarray(out[exponent_key.format(j=j)], np.float64)
        cabs = np.max([np.abs(out[f"{nm}_{j}"][:, :1]) for nm in names], axis=0)
        lobes.append((out[f"rho_s_{j}"], cabs, np.exp(n) if log else n))
    factors, changed = bound_lobes(out["rho_d"], lobes, limits)
    for j, (r_scale, c_scale, n_new, dead) in enumerate(factors, start=1):
        out[f"rho_s_{j}"] = out[f"rho_s_{j}"] * r_scale
        for nm in names:
            out[f"{nm}_{j}"] = out[f"{nm}_{j}"] * c_scale
        out[exponent_key.format(j=j)] = np.log(n_new) if log else n_new
        if reset_dead:
            neutralise(model, out, j, dead)
    return changed


def neutralise(model, out, j: int, dead: np.ndarray) -> None:
    """Lobe ``j`` of model-form ``out`` reset in place where ``dead`` ``(T, 1)``: ρ_s = 0, C at the text's initial
    lobe, n = :data:`NEUTRAL_EXPONENT`, a shape that stays harmless when quantized or interpolated."""
    if not np.any(dead):
        return
    c0 = INITIAL_LOBES[min(j, 2) - 1][0]
    out[f"rho_s_{j}"] = np.where(dead, 0.0, out[f"rho_s_{j}"])
    out[f"exponent_{j}"] = np.where(dead, NEUTRAL_EXPONENT, out[f"exponent_{j}"])
    for nm in (("c_x", "c_y") if model.anisotropic else ("c_xy",)):
        out[f"{nm}_{j}"] = np.where(dead, c0, out[f"{nm}_{j}"])
