"""Batched Levenberg–Marquardt for any BRDF model: the solver the ``lm`` fitter, McAllister's lobe fit,
the measured-table refinement and the mip re-fit share.

All texels of a tile are solved together: residuals ``(T, M)``, Jacobians
``(T, M, K)`` from the model (analytic where it has one), normal equations
``(T, K, K)`` solved in one batched call, and a per-texel damping λ that
shrinks on success and grows on failure (Marquardt's diagonal scaling).  Each
iteration works only on the texels still improving, so a tile costs what its
hardest texels need.

The fit runs in the model's *fit form* (:meth:`BRDFModel.fit_form`): for
Lafortune lobes C_z = 1 and log n, which removes the ρ_s ↔ |C|^n degeneracy
of the raw form.  Every trial point is clipped to the fit form's bounds and
projected by the model's :meth:`~sbrdf_core.brdf.BRDFModel.constrain` onto the
texel's :class:`~sbrdf_core.constraints.Limits` (bounded peak, resolvable
sharpness), so the fit is the best one *inside* them, not a clipped
unbounded one.  Parameters named in ``fixed`` keep their initial value.

Starting points do not depend on luck: the model's own initial guess and a
Sobol set over the parameters' typical ranges, each with its magnitudes
solved linearly (:meth:`~sbrdf_core.brdf.BRDFModel.refine_linear`), are
scored per texel, and LM runs from the ``starts`` best of them; the texel keeps
its best result.  ``loss: huber`` or ``soft-l1`` reweights samples by their
residual (iteratively reweighted least squares) so a few outliers (dust,
specular spikes) do not pull the lobes.
"""

from __future__ import annotations

import logging

import numpy as np

from sbrdf_core.channels import abs_channel_mean
from sbrdf_core.contracts import optional
from sbrdf_core.nodes.fit import usable

from .lm_params import WEIGHTINGS

__all__ = [
    "EXACT",
    "IRLS_ROUNDS",
    "LOSSES",
    "MAX_DAMPING",
    "Projection",
    "candidate_starts",
    "cost_outliers",
    "diffuse_percentile",
    "fit_model",
    "keep_better",
    "levenberg_marquardt",
    "projector",
    "rescue",
    "robust_weights",
    "sample_weights",
    "starting_points",
    "total_cost",
    "valid_median",
]

logger = logging.getLogger(__name__)

#: A texel stops when λ exceeds this: no step along the gradient helps any more.
MAX_DAMPING = 1e10
#: Cost below this fraction of the data's energy counts as an exact fit.
EXACT = 1e-24


def least_squares(form, f_r, weight, wi, wo):
    """The problem :func:`levenberg_marquardt` solves for ``form``: the engine's compiled one where the form has a
    fit kernel (:mod:`sbrdf_core.engine`), else the form's own (:meth:`~sbrdf_core.brdf.BRDFModel.least_squares`)."""
    from sbrdf_core.engine import compiled_problem

    problem = compiled_problem(form, f_r, weight, wi, wo)
    return form.least_squares(f_r, weight, wi, wo) if problem is None else problem


def levenberg_marquardt(problem, x0: np.ndarray, bounds: tuple[np.ndarray, np.ndarray], *, iterations: int = 50,
                        tolerance: float = 1e-4, damping: float = 1e-3, free: np.ndarray | None = None, project=None,
                        max_step: np.ndarray | None = None):
    """Minimise each texel's cost in ``problem`` (a :class:`~sbrdf_core.least_squares.LeastSquaresProblem`).

    Each trial point is evaluated with its normal equations in one call: an
    accepted step (most of them) then needs no second evaluation, which saves
    about a third of the work over evaluating the cost first.  ``project(x,
    idx)``, if given, maps each clipped trial point into the feasible set
    (:func:`projector`).  ``max_step`` ``(K,)``, if given, is the longest a
    step may move each parameter (the form's optional ``max_step``): a longer
    step is shortened along its direction (:func:`limit_step`).  Returns ``(x, cost, converged)``; texels whose
    weights are all zero stay at ``x0``.  A problem with its own
    ``levenberg_marquardt`` (the fitting engine's, :mod:`sbrdf_core.engine`)
    runs this same iteration per texel in its compiled loop where the
    projection is the form's own (:class:`Projection`).
    """
    T, K = x0.shape
    lo, hi = bounds
    free = np.ones(K, bool) if free is None else np.asarray(free, bool)
    compiled = getattr(problem, "levenberg_marquardt", None)
    if compiled is not None and (project is None or (isinstance(project, Projection) and project.form is problem.form)):
        x, cost, converged = compiled(x0, bounds, iterations=iterations, tolerance=tolerance, damping=damping,
                                      free=free, limits=None if project is None else project.limits, exact=EXACT,
                                      max_damping=MAX_DAMPING, max_step=max_step)
        if project is None or getattr(problem, "projects", True):
            return x, cost, converged
        # The engine held the box; project onto the rest of the limits and refine, inside them, what moved.
        xp = project(x, np.arange(T))
        moved = np.flatnonzero(np.abs(xp - x).max(axis=1) > 1e-9 * (1.0 + np.abs(x).max(axis=1)))
        if moved.size:
            x[moved], cost[moved], converged[moved] = _lm_loop(
                problem, xp[moved], moved, bounds, iterations, tolerance, damping, free, project, max_step)
        return x, cost, converged
    return _lm_loop(problem, x0, np.arange(T), bounds, iterations, tolerance, damping, free, project, max_step)


def _lm_loop(problem, x0, rows, bounds, iterations, tolerance, damping, free, project, max_step):
    """The NumPy iteration of :func:`levenberg_marquardt` for the problem's texels ``rows`` (``x0`` their starts)."""
    T, K = x0.shape
    lo, hi = bounds
    outer_free = np.outer(free, free)
    x = np.clip(x0, lo, hi)
    if project is not None:
        x = project(x, rows)
    A, g, cost = problem.normal_equations(x, rows)
    A, g = A * outer_free, g * free
    lam = np.full(T, damping)
    active = (problem.weight.reshape(problem.weight.shape[0], -1)[rows] > 0).any(axis=1) & (cost > 0) & np.isfinite(cost)
    # A fit this close to the data is exact to round-off (noiseless data): further
    # steps keep halving the cost without changing the parameters.
    exact = EXACT * problem.data_energy()[rows]
    eye = np.eye(K)
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        xa, Aa, ga = x[idx], A[idx], g[idx]
        diag = np.where(free, np.maximum(np.einsum("tkk->tk", Aa), 1e-12), 1.0)
        with np.errstate(all="ignore"):
            step = -np.linalg.solve(Aa + (lam[idx, None] * diag)[:, :, None] * eye, ga[..., None])[..., 0]
        step = limit_step(np.where(np.isfinite(step), step, 0.0), max_step)
        x_new = np.clip(xa + step, lo, hi)
        if project is not None:
            x_new = project(x_new, rows[idx])
            x_new = _active_set_step(Aa, ga, diag, lam[idx], free, xa, step, x_new, lo, hi, project, rows[idx],
                                     max_step)
            step = x_new - xa
        A_new, g_new, cost_new = problem.normal_equations(x_new, rows[idx])
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


def limit_step(step: np.ndarray, max_step: np.ndarray | None) -> np.ndarray:
    """Rows of ``step`` ``(n, K)`` shortened along their direction so no parameter moves more than ``max_step``.

    Why: far from the minimum a Gauss–Newton step can be far longer than the
    region where the model is near linear (a Lafortune lobe's exponent
    multiplied many times over); the trial point then costs more than the
    start, and LM spends evaluation after evaluation raising λ until the step
    is short enough.  Scaling the step keeps its direction, which λ does not.
    """
    if max_step is None:
        return step
    size = np.abs(step)
    with np.errstate(divide="ignore", over="ignore"):  # only where size > max_step is the ratio used
        scale = np.where(size > max_step, max_step / size, 1.0).min(axis=1)
    return step * scale[:, None]


def _active_set_step(A, g, diag, lam, free, x, step, x_new, lo, hi, project, idx, max_step=None):
    """The projected trial point, with the step solved again where the projection pinned a parameter.

    A parameter the projection held where it was (at its bound, the step
    pointing out) leaves the Gauss–Newton step of the others wrong: they were
    solved assuming it would move, so LM crawls along the bound, one small
    projected step per iteration.  Freezing the pinned parameters and solving
    for the rest (an active set) takes the constrained step directly.
    """
    scale = 1e-9 * np.maximum(np.abs(x), 1.0)
    pinned = (np.abs(x_new - (x + step)) > scale) & (np.abs(x_new - x) <= scale) & free
    rows = np.flatnonzero(pinned.any(axis=1))
    if rows.size == 0:
        return x_new
    keep = free & ~pinned[rows]  # (R, K)
    K = x.shape[1]
    outer = keep[:, :, None] & keep[:, None, :]
    Ar = np.where(outer, A[rows], 0.0) + (~keep)[:, :, None] * np.eye(K)
    d = np.where(keep, diag[rows], 1.0)
    with np.errstate(all="ignore"):
        s = -np.linalg.solve(Ar + (lam[rows, None] * d)[:, :, None] * np.eye(K), (g[rows] * keep)[..., None])[..., 0]
    s = limit_step(np.where(np.isfinite(s) & keep, s, 0.0), max_step)
    out = x_new.copy()
    out[rows] = project(np.clip(x[rows] + s, lo, hi), idx[rows])
    return out


class Projection:
    """``project(x, idx)`` for :func:`levenberg_marquardt`: fit-form rows of texels ``idx`` through
    ``form.constrain`` onto their ``limits``, compiled where the engine can (:func:`sbrdf_core.engine.project`:
    the form's projection kernel, or its box and peak widening).  A problem that solves LM itself (``levenberg_marquardt``) reads ``form``
    and ``limits`` to project there."""

    def __init__(self, form, limits):
        self.form, self.limits = form, limits

    def __call__(self, x, idx):
        from sbrdf_core.engine import project

        limits = self.limits.take(idx)
        out = project(self.form, x, limits)
        if out is not None:
            return out
        params, _ = self.form.constrain(self.form.unpack(x), limits)
        return self.form.pack(params)


def projector(form, limits) -> Projection | None:
    """The :class:`Projection` onto ``limits`` (None: no limits, no projection)."""
    return None if limits is None else Projection(form, limits)


#: Candidates × texels × samples up to which :func:`candidate_starts` solves every candidate's magnitudes at once.
BATCHED_CANDIDATE_SAMPLES = 1 << 20


def candidate_starts(form, f_r, valid, wi, wo, count: int, seed: int = 0, first=None) -> list[dict[str, np.ndarray]]:
    """``first`` (default: the form's initial guess) and ``count − 1`` Sobol points over the typical ranges,
    magnitudes solved.

    The same points for every texel, so a fit is reproducible and covers
    the shape space evenly rather than by a random draw per texel.
    """
    from scipy.stats import qmc

    T = f_r.shape[0]
    out = [form.initial_guess(f_r, valid, wi, wo) if first is None else first]
    shape = [p for p in form.parameters if not p.magnitude]
    dims = sum(p.channels for p in shape)
    if count > 1 and dims:
        points = qmc.Sobol(dims, scramble=True, seed=seed).random(1 << int(np.ceil(np.log2(count - 1))))[:count - 1]
        guesses = []
        for point in points:
            guess = form.defaults(T)
            k = 0
            for p in shape:
                lo, hi = p.typical
                guess[p.name] = np.broadcast_to(lo + (hi - lo) * point[k:k + p.channels], (T, p.channels)).copy()
                k += p.channels
            guesses.append(guess)
        C = len(guesses)
        if C * T * f_r.shape[1] <= BATCHED_CANDIDATE_SAMPLES:
            # Few texels (a rescue): every candidate's magnitudes in one solve, texels repeated per candidate,
            # instead of one solve per candidate that costs its calls, not its texels.
            tile = lambda a: np.concatenate([a] * C)  # noqa: E731
            solved = form.refine_linear({k: np.concatenate([g[k] for g in guesses]) for k in guesses[0]},
                                        tile(f_r), tile(valid), tile(wi), tile(wo))
            out += [{k: v[c * T:(c + 1) * T] for k, v in solved.items()} for c in range(C)]
        else:
            out += [form.refine_linear(guess, f_r, valid, wi, wo) for guess in guesses]
    return out


def robust_weights(form, x, f_r, valid, wi, wo, loss: str, scale: float) -> np.ndarray:
    """IRLS weights √ρ'(z), z = (r/δ)², for Huber or soft-L1 on each sample's RGB residual norm.

    δ = ``scale`` (sr⁻¹) or, when 0, 1.4826 × the texel's median absolute
    residual (the noise level a Gaussian would have), floored so an exact
    fit does not divide by zero.
    """
    with np.errstate(all="ignore"):
        r = np.linalg.norm(form.eval(form.unpack(x), wi, wo) - f_r, axis=-1)
    r = np.where(valid & np.isfinite(r), r, 0.0)
    if scale > 0:
        delta = np.full((r.shape[0], 1), float(scale))
    else:
        med = np.nanmedian(np.where(valid, r, np.nan), axis=1, keepdims=True)
        floor = 1e-3 * np.abs(f_r).max(axis=(1, 2))[:, None] + 1e-9
        delta = np.maximum(1.4826 * np.nan_to_num(med), floor)
    z = (r / delta) ** 2
    rho_prime = np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0))) if loss == "huber" else 1.0 / np.sqrt(1.0 + z)
    return valid * np.sqrt(rho_prime)


LOSSES = ("linear", "huber", "soft-l1")
#: The weights' floor, as a fraction of the texel's median sample (RGB mean).
WEIGHT_FLOOR = 0.5


def sample_weights(f_r: np.ndarray, valid: np.ndarray, power: float, floor: float = WEIGHT_FLOOR) -> np.ndarray:
    """Per-sample weights ``(T, S)`` 1 / (|f_r| + floor · the texel's median)^power, the largest 1; 0 where invalid.

    Why: an absolute least squares is ruled by the few samples at a peak, so
    the fit of a model that cannot follow the data (a Lafortune lobe for a
    GGX one) gives up the tails, where f_r is small and a render still shows
    every relative error.  Power ½ is the maximum-likelihood weighting of a
    photographed value under shot noise (its variance grows with the signal);
    power 1 fits the shape in ratio.  The floor, relative to the texel's own
    level so the weights do not depend on the exposure scale, stands for the
    noise that does not grow with the signal and keeps near-zero samples from
    taking over.
    """
    if power == 0.0:
        return valid.astype(np.float64)
    valid = np.asarray(valid, bool)
    y = abs_channel_mean(f_r)
    level = valid_median(y, valid)
    with np.errstate(all="ignore"):
        w = np.where(valid, (np.where(valid, y, 0.0) + floor * level + 1e-12) ** -power, 0.0)
    return w / np.maximum(w.max(axis=1, keepdims=True), 1e-300)


def valid_median(y: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Median of each row's valid entries, ``(T, 1)``; 1 for a row with none.

    ``np.nanmedian`` of the same rows, bit for bit, from one sort of the whole
    array (invalid entries last) instead of numpy's masked-array path: 8x
    faster at 4096 texels x 400 samples, where it was a tenth of a fit.
    """
    s = np.sort(np.where(valid, y, np.inf), axis=1)
    n = valid.sum(axis=1)
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0)[:, None], axis=1)
    hi = np.take_along_axis(s, np.minimum(n // 2, s.shape[1] - 1)[:, None], axis=1)
    with np.errstate(all="ignore"):
        return np.where(n[:, None] > 0, (lo + hi) / 2, 1.0)

#: Reweighting rounds of a robust loss (each an LM run from the last result).
IRLS_ROUNDS = 4


def fit_model(model, f_r, valid, wi, wo, *, initial=None, iterations=50, tolerance=1e-4, damping=1e-3,
              fixed=(), starts=1, seed=0, limits=None, loss="linear", loss_scale=0.0, stats=None,
              weighting="absolute", want_cost=True, checked=False):
    """LM fit of ``model`` in its fit form; returns ``(params in model form, converged, cost)``.

    ``cost`` is each texel's final sum of squared residuals over its valid
    samples (all channels, unweighted even for a robust loss), so
    RMS = sqrt(cost / (channels · samples)).

    ``initial``: fit-form parameters to start from (default: the form's
    initial guess).  ``starts``: LM runs per texel (0: ``model.suggested_starts``);
    more than one scores ``8 · starts`` candidates (:func:`candidate_starts`)
    and runs from each texel's best.  ``limits``: per-texel
    :class:`~sbrdf_core.constraints.Limits` every iterate is projected onto.
    ``fixed``: fit-form parameter names held constant.  ``stats``, a dict, gets
    ``restarted`` (``(T,)`` mask of texels whose best result came from a start
    other than their best-scored one).  ``weighting``:
    a key of :data:`WEIGHTINGS`, residuals weighted by :func:`sample_weights`
    (starts are scored and kept on that objective; ``cost`` stays unweighted).
    Texels the form flags as trapped
    (``fit_trapped``) are fitted again (:func:`rescue`).  ``want_cost``
    False: ``cost`` is ``None`` (a weighted fit's unweighted cost is a
    further pass over the samples, a fifteenth of a 1-lobe Fit tile, which
    a caller that scores the fit itself does not need).  ``checked``: ``f_r`` and ``valid`` are
    :func:`~sbrdf_core.nodes.fit.usable`'s output already (the Fit node's), so its pass is not made again.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss {loss!r} is not one of {', '.join(LOSSES)}")
    if weighting not in WEIGHTINGS:
        raise ValueError(f"weighting {weighting!r} is not one of {', '.join(WEIGHTINGS)}")
    starts = starts or model.suggested_starts
    form = model.fit_form()
    T = f_r.shape[0]
    f_r, valid = (np.asarray(f_r, np.float64), np.asarray(valid, bool)) if checked else usable(f_r, valid)
    lo, hi = form.bounds()
    free = np.ones(form.size, bool)
    slices = form.slices()
    for name in fixed:
        if name not in slices:
            raise ValueError(f"fixed parameter {name!r} is not a parameter of {form.name}; known: {', '.join(slices)}")
        free[slices[name]] = False
    project = projector(form, limits)
    max_step = optional(form, "max_step", "brdf-model")
    everyone = np.arange(T)
    base = sample_weights(f_r, valid, WEIGHTINGS[weighting])  # absolute: valid as weights, the plain problem
    objective = least_squares(form, f_r, base, wi, wo)
    x_starts = starting_points(form, objective, f_r, valid, wi, wo, starts, seed, initial, free, project)
    logger.debug("LM fit of %s: %d texels, %d start(s), loss %s, %s weighting", form.name, T, len(x_starts), loss,
                 weighting)
    opts = dict(iterations=iterations, tolerance=tolerance, damping=damping, free=free, max_step=max_step)

    def descend(x, rows=None):
        """LM (with the robust loss's reweighting) from ``x`` for texels ``rows`` (all by default)."""
        fr, vd, a, b, w0 = (v if rows is None else v[rows] for v in (f_r, valid, wi, wo, base))
        obj = objective if rows is None else least_squares(form, fr, w0, a, b)
        proj = project if rows is None or limits is None else projector(form, limits.take(rows))
        weight = w0
        for _ in range(1 if loss == "linear" else IRLS_ROUNDS):
            problem = obj if loss == "linear" else least_squares(form, fr, weight, a, b)
            x, cost, converged = levenberg_marquardt(problem, x, (lo, hi), project=proj, **opts)
            if loss != "linear":
                weight = robust_weights(form, x, fr, vd, a, b, loss, loss_scale) * w0
        if loss != "linear":
            cost = total_cost(obj, x)
        return x, cost, converged

    best = None
    for x in x_starts:
        xs, cost, converged = descend(x)
        best = keep_better(best, xs, cost, converged, 1e-9)
    assert best is not None
    best = rescue(form, best, f_r, valid, wi, wo, base, seed, free, limits, descend, 1e-9)
    nested = optional(form, "nested", "brdf-model")
    inner = nested() if nested is not None and initial is None and free.all() else None
    if inner is not None:
        # More freedom never fits worse: the smaller model's solution, embedded (the extra lobe dead), competes.
        smaller, embed = inner
        small, small_converged, _ = fit_model(smaller, f_r, valid, wi, wo, iterations=iterations, tolerance=tolerance,
                                damping=damping, starts=starts if starts != model.suggested_starts else 0,
                                seed=seed, limits=limits, loss=loss, loss_scale=loss_scale, weighting=weighting,
                                want_cost=False, checked=True)
        sform = smaller.fit_form()
        x_in = np.clip(embed(sform.pack(sform.from_model(small))), lo, hi)
        if project is not None:
            x_in = project(x_in, everyone)
        compete(model, form, best, x_in, small_converged, objective, descend, limits, (lo, hi),
                least_squares(form, f_r, valid.astype(np.float64), wi, wo)
                if weighting != "absolute" or loss != "linear" else None)
    x, cost, converged, restarted = best
    if not want_cost:
        cost = None
    elif weighting != "absolute":  # unweighted, whatever was minimised (a robust loss's cost already is)
        cost = total_cost(least_squares(form, f_r, valid.astype(np.float64), wi, wo), x)
    if stats is not None:
        stats["restarted"] = restarted
    return form.to_model(form.unpack(x)), converged, cost


def compete(model, form, best, x_in, converged, objective, descend, limits, bounds, plain) -> None:
    """The smaller model's embedded solution ``x_in`` against :func:`fit_model`'s ``best`` (updated in place): as it
    is, and as the start of one more LM run (``descend``; the dead lobe's magnitude has a gradient, so it can wake).

    Where the Fit node will hold an energy bound (``limits.albedo``) both compete as they will leave the node,
    else the larger model's scaled-down solution could end above the smaller one's.  ``plain``: the unweighted
    problem, when the objective is weighted: where ``x_in`` has the lower plain error it is kept, so the error
    users read never grows with the model either.
    """
    keep_better(best, x_in, total_cost(objective, x_in), converged.copy(), 0.0)
    x_down, cost_down, converged_down = descend(x_in)
    keep_better(best, x_down, cost_down, converged_down, 0.0)
    if limits is not None and limits.albedo is not None:
        best[0] = within_energy(model, form, best[0], limits.albedo, *bounds)
        best[1] = total_cost(objective, best[0])
        x_in = within_energy(model, form, x_in, limits.albedo, *bounds)
        keep_better(best, x_in, total_cost(objective, x_in), converged.copy(), 0.0)
    if plain is not None:
        lower = total_cost(plain, x_in) < total_cost(plain, best[0]) * (1 - 1e-12)
        best[0][lower], best[2][lower] = x_in[lower], converged[lower]
        best[1][lower] = objective.cost(x_in[lower], np.flatnonzero(lower))


def within_energy(model, form, x: np.ndarray, albedo: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Packed fit-form rows ``x`` with the magnitudes scaled so the directional albedo is ≤ ``albedo``
    (:func:`~sbrdf_core.constraints.enforce_energy`, as the Fit node holds it)."""
    from sbrdf_core.constraints import enforce_energy

    params, changed = enforce_energy(model, form.to_model(form.unpack(x)), albedo)
    if not changed.any():
        return x
    out = x.copy()
    rows = np.flatnonzero(changed)
    out[rows] = np.clip(form.pack(form.from_model({k: v[rows] for k, v in params.items()})), lo, hi)
    return out


def starting_points(form, objective, f_r, valid, wi, wo, starts: int, seed: int = 0, initial=None, free=None,
                    project=None, keep_first: bool = True) -> list[np.ndarray]:
    """The packed fit-form points LM runs from: with ``starts`` > 1, the first candidate (the initial guess, or
    ``initial``) and the ``starts − 1`` best-scoring (on ``objective``, the problem the fit minimises, weighted as
    it is) of the other ``8 · starts − 1`` candidates (:func:`candidate_starts`), per texel; parameters not
    ``free`` keep the first candidate's value; every start is projected by ``project``.  What :func:`fit_model`
    and the ``lm-gl`` fitter both start from.

    Why the first always runs: a start's score is its cost before LM, not after.  Ranked with the others,
    the guess lost its place to Sobol points that scored better and ended worse: with ``starts: 4``, one lobe
    on a broad back-scattering material (C_xy = 0.95, n = 3) ended 478 of 1024 texels above twice the noise
    where one start ended none (benchmarks/fit.py's shape sweep).  Kept, more starts never end worse than
    one.  ``keep_first=False`` ranks it with the rest (the rescue, whose first candidate is the result it
    tries to beat)."""
    T = f_r.shape[0]
    lo, hi = form.bounds()
    everyone = np.arange(T)
    count = 8 * starts if starts > 1 else 1
    cands = [np.clip(form.pack(c), lo, hi) for c in candidate_starts(form, f_r, valid, wi, wo, count, seed, initial)]
    if free is not None:
        for c in cands[1:]:  # fixed parameters keep the initial guess's value in every start
            c[:, ~free] = cands[0][:, ~free]
    if project is not None:
        cands = [project(c, everyone) for c in cands]
    if len(cands) == 1:
        return cands
    first = 1 if keep_first else 0
    costs = np.stack([total_cost(objective, c) for c in cands[first:]])  # (C, T)
    order = np.argsort(np.where(np.isfinite(costs), costs, np.inf), axis=0, kind="stable") + first
    stack = np.stack(cands)  # (C, T, K)
    return cands[:first] + [stack[order[r], everyone] for r in range(min(starts, len(cands)) - first)]


#: Multi-start candidates a trapped texel (:func:`rescue`) is fitted again from, its current result among them.
RESCUE_STARTS = 4


def rescue(form, best, f_r, valid, wi, wo, weight, seed, free, limits, descend, margin: float):
    """Fit again the texels ``form.fit_trapped`` flags in ``best`` (:func:`keep_better`'s list, updated in place),
    and those whose cost is an outlier in the batch where the form sets ``fit_outlier_ratio`` (:func:`cost_outliers`).

    A texel's result competes with LM runs from the :data:`RESCUE_STARTS` best
    of ``8 ·`` that many candidates (:func:`starting_points`, scored on the
    objective ``weight`` makes), its current result the first candidate; it
    takes a lower cost.  ``descend(x0, rows) -> (x, cost, converged)`` is the fitter's own LM
    on those texels, so ``lm`` and ``lm-gl`` rescue alike.
    Why: a few texels of a multi-lobe fit lose a lobe, and a single start
    gives them a training RMS 2-4× the noise; restarting every texel would
    cost a whole fit, these few cost ~1% of one.
    """
    trapped = optional(form, "fit_trapped", "brdf-model")
    flagged = np.zeros(best[1].shape[0], bool) if trapped is None else trapped(best[0])
    ratio = optional(form, "fit_outlier_ratio", "brdf-model")
    if ratio is not None:
        flagged |= cost_outliers(best[1], valid, ratio)
    rows = np.flatnonzero(flagged)
    if rows.size == 0:
        return best
    sub_project = projector(form, None if limits is None else limits.take(rows))
    sub = [v[rows].copy() for v in best]
    objective = least_squares(form, f_r[rows], weight[rows], wi[rows], wo[rows])
    starts = starting_points(form, objective, f_r[rows], valid[rows], wi[rows], wo[rows], RESCUE_STARTS, seed,
                             form.unpack(best[0][rows]), free, sub_project, keep_first=False)
    # All starts in one LM run (each texel repeated per start): its cost is per iteration, not per texel.
    x, cost, converged = descend(np.concatenate(starts), np.tile(rows, len(starts)))
    for k in range(len(starts)):
        part = slice(k * rows.size, (k + 1) * rows.size)
        keep_better(sub, x[part], cost[part], converged[part], margin)
    logger.debug("%s: %d trapped texels fitted again (multi-start), %d improved", form.name, rows.size,
                 int((sub[1] < best[1][rows]).sum()))
    for v, part in zip(best, sub):
        v[rows] = part
    return best


def cost_outliers(cost: np.ndarray, valid: np.ndarray, factor: float) -> np.ndarray:
    """Texels whose cost per valid sample is over ``factor`` × the batch's (a tile's) median, ``(T,)``.

    What a form's ``fit_outlier_ratio`` asks :func:`rescue` to fit again: LM
    from one start can settle with two lobes on one feature or a bright lobe
    at the exponent bound; no lobe is dead, so ``fit_trapped`` sees nothing,
    but the texel fits several times worse than its tile's typical texel.  The
    rescue keeps a new result only where its cost is lower, so a texel flagged
    for a harder material than its neighbours' costs time, not accuracy.
    Fewer than 8 texels with samples: no median to trust, nothing flagged.
    """
    n = np.asarray(valid, bool).sum(axis=1)
    has = (n > 0) & np.isfinite(cost)
    if has.sum() < 8:
        return np.zeros(cost.shape[0], bool)
    per = np.where(has, cost / np.maximum(n, 1), 0.0)
    return has & (per > factor * np.median(per[has]))


def keep_better(best, x, cost, converged, margin: float):
    """Fold one start's result into ``best`` (``[x, cost, converged, restarted]`` or None): a texel takes it where
    its cost is lower by more than the relative ``margin``, and is then marked restarted."""
    if best is None:
        return [x, cost, converged, np.zeros(len(cost), bool)]
    better = cost < best[1] * (1 - margin)
    best[0][better], best[1][better], best[2][better] = x[better], cost[better], converged[better]
    best[3] |= better
    return best


def total_cost(problem, x) -> np.ndarray:
    """Each texel's sum of squared (weighted) residuals at the fit-form points ``x``, ``(T,)``: the problem's
    ``cost`` where it has one (no Jacobian), else its normal equations' cost."""
    everyone = np.arange(x.shape[0])
    cost = getattr(problem, "cost", None)
    return cost(x, everyone) if cost is not None else problem.normal_equations(x, everyone)[2]


def diffuse_percentile(f_r: np.ndarray, valid: np.ndarray, percentile: float) -> np.ndarray:
    """Per-channel percentile of each texel's valid samples, ``(T, 3)``; 0 for a texel with none.

    McAllister's ρ_d estimate (§4.3): the minimum is biased low by noise and
    registration error, so a low percentile (10th by default) is used.
    Vectorised (``np.nanpercentile`` loops over texels in Python): invalid
    samples sort to the end, and each texel interpolates linearly between
    its own order statistics, as numpy's default method does.
    """
    # (T, C, S): each texel's channel sorted as one contiguous row (NumPy's SIMD sort runs on contiguous rows, not
    # on the strided sample axis of (T, S, C)).  Photographed values are float32, and then sorted as such: the same
    # order statistics, in twice the SIMD lanes.
    if f_r.shape[1] == 0:  # no samples at all
        return np.zeros((f_r.shape[0], f_r.shape[-1]))
    # Invalid samples set to inf in the copy by a boolean index, which writes only those samples where np.where
    # would broadcast the mask over the whole array.
    channels = np.moveaxis(f_r, -1, 1)
    narrow = channels.astype(np.float32)
    data = narrow if np.array_equal(narrow, channels) else channels.astype(np.float64)
    data[np.broadcast_to(~np.asarray(valid, bool)[:, None, :], data.shape)] = np.inf
    data.sort(axis=-1)
    n = valid.sum(axis=1)  # (T,)
    pos = np.clip(percentile / 100.0 * (n - 1), 0, None)
    lo = np.floor(pos).astype(int)
    hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
    frac = (pos - lo)[:, None]
    rows = np.arange(len(n))
    a, b = data[rows, :, lo].astype(np.float64), data[rows, :, hi].astype(np.float64)  # (T, C)
    with np.errstate(invalid="ignore"):  # inf − inf in texels without samples, masked below
        out = np.where(frac > 0, a + frac * (b - a), a)
    return np.clip(np.where((n > 0)[:, None] & np.isfinite(out), out, 0.0), 0.0, None)
