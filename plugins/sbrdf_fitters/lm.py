"""lm: Levenberg–Marquardt for any BRDF model, batched over texels.

All texels of a tile are solved together: residuals ``(T, M)``, Jacobians
``(T, M, K)`` from the model (analytic where it has one), normal equations
``(T, K, K)`` solved in one batched call, and a per-texel damping λ that
shrinks on success and grows on failure (Marquardt's diagonal scaling).  Each
iteration works only on the texels still improving, so a tile costs what its
hardest texels need.

The fit runs in the model's *fit form* (:meth:`BRDFModel.fit_form`): for
Lafortune lobes C_z = 1 and log n, which removes the ρ_s ↔ |C|^n degeneracy
of the raw form.  Parameters are clipped to the fit form's bounds; parameters
named in ``fixed`` keep their initial value.  ``starts`` > 1 adds random
starts (shape from each parameter's typical range, magnitudes solved
linearly) and keeps each texel's best.
"""

from __future__ import annotations

import warnings
import numpy as np

from sbrdf_core.nodes.fit import NOT_CONVERGED, FitResult, usable

#: A texel stops when λ exceeds this: no step along the gradient helps any more.
MAX_DAMPING = 1e10
#: Cost below this fraction of the data's energy counts as an exact fit.
EXACT = 1e-24


def levenberg_marquardt(problem, x0: np.ndarray, bounds: tuple[np.ndarray, np.ndarray], *, iterations: int = 50,
                        tolerance: float = 1e-4, damping: float = 1e-3, free: np.ndarray | None = None):
    """Minimise each texel's cost in ``problem`` (a :class:`~sbrdf_core.least_squares.LeastSquaresProblem`).

    Each trial point is evaluated with its normal equations in one call: an
    accepted step (most of them) then needs no second evaluation, which saves
    about a third of the work over evaluating the cost first.  Returns
    ``(x, cost, converged)``; texels whose weights are all zero stay at ``x0``.
    """
    T, K = x0.shape
    lo, hi = bounds
    free = np.ones(K, bool) if free is None else np.asarray(free, bool)
    outer_free = np.outer(free, free)
    x = np.clip(x0, lo, hi)
    everyone = np.arange(T)
    A, g, cost = problem.normal_equations(x, everyone)
    A, g = A * outer_free, g * free
    lam = np.full(T, damping)
    active = (problem.weight.reshape(T, -1) > 0).any(axis=1) & (cost > 0) & np.isfinite(cost)
    # A fit this close to the data is exact to round-off (noiseless data): further
    # steps keep halving the cost without changing the parameters.
    exact = EXACT * problem.data_energy()
    eye = np.eye(K)
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        xa, Aa, ga = x[idx], A[idx], g[idx]
        diag = np.where(free, np.maximum(np.einsum("tkk->tk", Aa), 1e-12), 1.0)
        with np.errstate(all="ignore"):
            step = -np.linalg.solve(Aa + (lam[idx, None] * diag)[:, :, None] * eye, ga[..., None])[..., 0]
        step = np.where(np.isfinite(step), step, 0.0)
        x_new = np.clip(xa + step, lo, hi)
        A_new, g_new, cost_new = problem.normal_equations(x_new, idx)
        better = np.isfinite(cost_new) & (cost_new < cost[idx])
        gain = np.where(better, (cost[idx] - cost_new) / np.maximum(cost[idx], 1e-300), 0.0)
        x[idx] = np.where(better[:, None], x_new, xa)
        A[idx] = np.where(better[:, None, None], A_new * outer_free, Aa)
        g[idx] = np.where(better[:, None], g_new * free, ga)
        cost[idx] = np.where(better, cost_new, cost[idx])
        lam[idx] = np.where(better, np.maximum(lam[idx] / 3.0, 1e-12), lam[idx] * 4.0)
        # Converged: an accepted step gained almost nothing, or a rejected one was
        # already negligible (round-off, not a bad direction: no need to grow λ).
        negligible = np.abs(step).max(axis=1) <= 1e-9 * np.maximum(np.abs(xa).max(axis=1), 1e-12)
        done = (better & (gain < tolerance)) | (~better & negligible) | (lam[idx] > MAX_DAMPING) | (cost[idx] <= exact[idx])
        active[idx[done]] = False
    return x, cost, ~active


def fit_model(model, f_r, valid, wi, wo, *, initial=None, iterations=50, tolerance=1e-4, damping=1e-3,
              fixed=(), starts=1, seed=0):
    """LM fit of ``model`` in its fit form; returns ``(params in model form, converged, cost)``.

    ``cost`` is each texel's final sum of squared residuals over its valid
    samples (all channels), so RMS = sqrt(cost / (channels · samples)).

    ``initial``: fit-form parameters to start from (default: the form's
    ``initial_guess``).  ``fixed``: fit-form parameter names held constant.
    """
    form = model.fit_form()
    T = f_r.shape[0]
    f_r, valid = usable(f_r, valid)
    problem = form.least_squares(f_r, valid.astype(np.float64), wi, wo)
    lo, hi = form.bounds()
    free = np.ones(form.size, bool)
    slices = form.slices()
    for name in fixed:
        if name not in slices:
            raise ValueError(f"fixed parameter {name!r} is not a parameter of {form.name}; known: {', '.join(slices)}")
        free[slices[name]] = False
    start = initial if initial is not None else form.initial_guess(f_r, valid, wi, wo)
    x0 = np.clip(form.pack(start), lo, hi)
    opts = dict(iterations=iterations, tolerance=tolerance, damping=damping, free=free)
    x, cost, converged = levenberg_marquardt(problem, x0, (lo, hi), **opts)
    rng = np.random.default_rng(seed)
    for _ in range(starts - 1):
        guess = form.random_guess(rng, T)
        for name in fixed:  # fixed parameters keep their given value in every start
            guess[name] = form.unpack(x0)[name]
        guess = form.refine_linear(guess, f_r, valid, wi, wo)
        xs, cs, conv = levenberg_marquardt(problem, np.clip(form.pack(guess), lo, hi), (lo, hi), **opts)
        better = cs < cost
        x[better], cost[better], converged[better] = xs[better], cs[better], conv[better]
    return form.to_model(form.unpack(x)), converged, cost


class LevenbergMarquardtFitter:
    """The ``lm`` fitter plugin (parameters: ``sbrdf_fitters.LM_PARAMS``)."""

    def __init__(self, model, model_params, iterations, tolerance, damping, starts, fixed, seed):
        self.model_name = model
        self.model_config = dict(model_params)
        self.iterations, self.tolerance, self.damping = iterations, tolerance, damping
        self.starts, self.fixed, self.seed = starts, tuple(fixed), seed
        if model == "lafortune" and int(model_params.get("lobes", 1)) >= 3 and starts == 1:
            warnings.warn("lm: with 3 or more Lafortune lobes the fit depends on the starting point "
                          "(seed 000 §4.3.1); consider starts: 8", stacklevel=2)

    def fit(self, model, f_r, valid, wi, wo) -> FitResult:
        f_r, valid = usable(f_r, valid)
        params, converged, cost = fit_model(model, f_r, valid, wi, wo, iterations=self.iterations,
                                            tolerance=self.tolerance, damping=self.damping, fixed=self.fixed,
                                            starts=self.starts, seed=self.seed)
        flags = np.where(converged, 0, NOT_CONVERGED).astype(np.uint8)
        n = valid.sum(axis=1)
        rms = np.sqrt(cost / np.maximum(f_r.shape[-1] * n, 1))  # the fit's own cost: no second evaluation
        return FitResult(params, rms, n, flags)
