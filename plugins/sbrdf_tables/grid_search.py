"""grid-search: Mühlbacher's hierarchical brute-force fit of kurt-transmissive lobes (seed 004 §3.4.1).

What the thesis does, and how it is vectorised here:

- **Metric** (Eq 3.7, with the |·| the prose asks for): on transfer
  probabilities p = f_s·|cos θ_o|, over M = the measured, non-zero entries,
  ``Σ sin θ_o |cos θ_i| |p_meas − p_model| / Σ sin θ_o``  (:func:`l1_error`).
- **k_d** outside the search: the mode of a histogram of the measured BSDF
  values of the reflection hemisphere (log-spaced bins, since the values span
  decades; the modal bin's median is k_d/π).
- **Hierarchical grid**: n equidistant values per free parameter of one lobe
  (k, m_x, m_y, r_0, α), keep the argmin, shrink the box to ± one grid step
  around it (clamped to the first box), repeat a fixed number of times;
  parameters can be fixed.  One level evaluates all n^P candidates at once
  by outer products: D depends on (m_x, m_y) only, F on r_0, the denominator
  on α and the coefficient is a factor, so the n^P × |M| predictions are built
  from n² + 2n direction arrays, a block of (m_y, r_0, α) at a time.
- **Several lobes**: alternate single-lobe searches, each fitted to the
  specular part minus the other lobes with negative residuals clamped to 0
  (§5.5 of the notes), for ``alternations`` passes.
- **Reflection and transmission** lobes are searched separately, each on its
  own hemisphere's entries (no diffuse term on the transmission side).
- ``lm_refine``: Levenberg–Marquardt (``sbrdf_lib.lm.levenberg_marquardt``)
  from the grid result, minimising the same weights in L2, so the two can be
  compared (benchmarks/bsdf_tables.py).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from sbrdf_core.nodes.fit import NOT_CONVERGED, FitResult, rms_error
from sbrdf_core.nodes.fit import usable as usable_samples

from .declarations import GRID_SEARCH
from .kurt import beckmann, lobe, lobe_geometry

logger = logging.getLogger(__name__)

#: Default search box of a lobe's (coefficient, m_x, m_y, r_0, α) when ``search`` does not name it.
DEFAULT_BOX = {"k": (0.0, 1.0), "m_x": (0.005, 0.5), "m_y": (0.005, 0.5), "r_0": (0.0, 1.0), "alpha": (0.0, 1.0)}
FIELDS = ("k", "m_x", "m_y", "r_0", "alpha")
#: Elements evaluated per block of the vectorised grid (memory, not speed: ~4 bytes each, 3 temporaries).
BLOCK_ELEMENTS = 8_000_000


def metric_weights(theta_i_deg, theta_o_deg) -> tuple[np.ndarray, np.ndarray]:
    """``(numerator weight sin θ_o |cos θ_i|, denominator weight sin θ_o)`` of Eq 3.7, per entry."""
    s = np.abs(np.sin(np.radians(theta_o_deg)))
    return s * np.abs(np.cos(np.radians(theta_i_deg))), s


def l1_error(p_measured, p_model, theta_i_deg, theta_o_deg, measured=None) -> float:
    """Eq 3.7: weighted mean |Δp| over the measured non-zero entries (NaN = unmeasured)."""
    p_measured = np.asarray(p_measured, float)
    use = np.isfinite(p_measured) & (p_measured != 0)
    if measured is not None:
        use &= np.asarray(measured, bool)
    num, den = metric_weights(theta_i_deg, theta_o_deg)
    if not use.any() or den[use].sum() == 0:
        return 0.0
    diff = np.abs(np.where(use, p_measured, 0.0) - np.asarray(p_model, float))
    return float(np.sum(np.where(use, num * diff, 0.0)) / den[use].sum())


def diffuse_from_histogram(f, bins: int = 64) -> float:
    """k_d = π × the mode of the positive BSDF values: the median of the most populated histogram bin; 0 if none.

    The thesis's premise is that most entries are off-specular, so the
    diffuse value is the most common one and the median of all values lies on
    that plateau.  Bins are linear over [0, 2 × median]: a linear density's
    mode sits at the plateau's value under symmetric sensor noise, which a
    log-binned density's does not (measured: 14 % high at 2 % noise).
    """
    f = np.asarray(f, float)
    f = f[np.isfinite(f) & (f > 0)]
    if f.size == 0:
        return 0.0
    top = 2.0 * np.median(f)
    edges = np.linspace(0.0, top, bins + 1)
    counts, _ = np.histogram(f, edges)
    k = int(np.argmax(counts))
    inside = f[(f >= edges[k]) & (f <= edges[k + 1])]
    return float(np.pi * np.median(inside))


@dataclass
class LobeSearch:
    """Result of one single-lobe hierarchical search."""

    values: dict[str, float]  # k, m_x, m_y, r_0, alpha
    error: float  # weighted L1 numerator sum at the optimum
    evaluations: int  # candidates evaluated (n^P per level)
    boxes: list = field(default_factory=list)  # (lo, hi) arrays per level, for tests and plots


def search_lobe(geometry, abs_cos_o, target, weight, transmission, *, n=9, iterations=4, box=None, fixed=None,
                keep_boxes=False) -> LobeSearch:
    """Hierarchical brute-force search of one lobe's (k, m_x, m_y, r_0, α) minimising Σ weight |target − k·lobe·|cos θ_o||.

    ``geometry``: :func:`sbrdf_tables.kurt.lobe_geometry` terms of the M entries;
    ``box``: field -> (lo, hi); ``fixed``: field -> value (that axis has one value).
    Level 1 spans the box with n values per free axis; each further level spans
    [best − step, best + step] clamped to the box, step = the previous level's spacing.
    """
    box = {**DEFAULT_BOX, **(box or {})}
    fixed = dict(fixed or {})
    lo0 = np.array([box[f][0] for f in FIELDS], float)
    hi0 = np.array([box[f][1] for f in FIELDS], float)
    for k, f in enumerate(FIELDS):
        if f in fixed:
            lo0[k] = hi0[k] = float(fixed[f])
    lo0[1:3] = np.maximum(lo0[1:3], 1e-4)  # roughness must stay positive: D divides by m
    hi0[1:3] = np.maximum(hi0[1:3], lo0[1:3])
    lo, hi = lo0.copy(), hi0.copy()
    t = np.asarray(target, np.float32)
    w = np.asarray(weight, np.float32)
    ac = np.asarray(abs_cos_o, np.float64)
    side = geometry["side"]
    best_x: np.ndarray | None = None
    best_err, evaluations, boxes = np.inf, 0, []
    for _level in range(iterations):
        axes = [np.linspace(lo[k], hi[k], n) if hi[k] > lo[k] else np.array([lo[k]]) for k in range(5)]
        if keep_boxes:
            boxes.append((lo.copy(), hi.copy()))
        ks, mxs, mys, r0s, alphas = axes
        # direction factors: F(r_0) (C, M), G(α) = |cos θ_o| / (4 cos_d cc^α) (Dα, M), D(m_x, m_y) per block
        F = np.stack([(1.0 - _schlick(geometry, r)) if transmission else _schlick(geometry, r) for r in r0s])
        G = np.stack([np.where(side, ac / (4.0 * geometry["cos_d"] * geometry["cc"] ** a), 0.0) for a in alphas])
        FG = (F[:, None, :] * G[None, :, :]).astype(np.float32)  # (C, Dα, M)
        err = np.empty((len(ks), len(mxs), len(mys), len(r0s), len(alphas)), np.float64)
        per_my = FG.size
        step_my = max(1, BLOCK_ELEMENTS // max(per_my, 1))
        for a, mx in enumerate(mxs):
            Dx = np.stack([beckmann(geometry, mx, my) for my in mys]).astype(np.float32)  # (B, M)
            for b0 in range(0, len(mys), step_my):
                S = Dx[b0:b0 + step_my, None, None, :] * FG[None]  # (b, C, Dα, M)
                buffer = np.empty_like(S)
                for e, k in enumerate(ks):  # |t − k S| in place: one buffer, no temporaries per candidate
                    np.multiply(S, np.float32(k), out=buffer)
                    np.subtract(t, buffer, out=buffer)
                    np.abs(buffer, out=buffer)
                    err[e, a, b0:b0 + step_my] = buffer @ w
        evaluations += err.size
        i = np.unravel_index(int(np.argmin(err)), err.shape)
        x = np.array([axes[k][i[k]] for k in range(5)])
        if err[i] < best_err:
            best_err, best_x = float(err[i]), x
        spacing = np.array([(axes[k][1] - axes[k][0]) if len(axes[k]) > 1 else 0.0 for k in range(5)])
        lo, hi = np.maximum(x - spacing, lo0), np.minimum(x + spacing, hi0)
    if best_x is None:
        raise ValueError(f"search_lobe: no candidate with a finite error in {iterations} level(s) of the search")
    return LobeSearch(dict(zip(FIELDS, map(float, best_x))), best_err, evaluations, boxes)


def _schlick(geometry, r_0):
    return r_0 + (1.0 - r_0) * (1.0 - geometry["cos_d"]) ** 5


def lobe_p(model_lobe, values, geometry, abs_cos_o):
    """p contributed by one lobe (k included) at the entries of ``geometry``."""
    *_, transmission = model_lobe
    return values["k"] * lobe(geometry, values["m_x"], values["m_y"], values["r_0"], values["alpha"], transmission) * abs_cos_o


@dataclass
class TableFit:
    """A grid-search (and optionally LM) fit of one table: model parameters (1 texel) and diagnostics."""

    params: dict[str, np.ndarray]
    l1: float
    l1_reflection: float
    l1_transmission: float
    evaluations: int
    seconds: float
    k_d: float
    converged: bool = True


def _model_values(model, params):
    return {name: float(np.asarray(v).reshape(-1)[0]) for name, v in params.items()}


def fit_table(model, theta_i, theta_o, wi, wo, p, *, n=9, iterations=4, alternations=2, search=None, fixed=None,
              histogram_bins=64) -> TableFit:
    """Grid-search fit of ``model`` (kurt-transmissive) to transfer probabilities ``p`` (M,) at ``wi``, ``wo`` (M, 3).

    ``search``: model parameter name -> [lo, hi]; ``fixed``: model parameter name -> value
    (``k_d`` fixed skips the histogram).  Entries with NaN or 0 are outside the metric.
    """
    t0 = time.perf_counter()
    search, fixed = dict(search or {}), dict(fixed or {})
    known = {q.name for q in model.parameters}
    for name in list(search) + list(fixed):
        if name not in known:
            raise ValueError(f"grid-search: {name!r} is not a parameter of {model.name}; known: {', '.join(sorted(known))}")
    p = np.asarray(p, float)
    use = np.isfinite(p) & (p != 0)
    p0 = np.where(use, p, 0.0)
    num, den = metric_weights(theta_i, theta_o)
    abs_cos_o = np.abs(wo[:, 2])
    down = wo[:, 2] < 0
    refl, trans = use & ~down, use & down
    if "k_d" in fixed:
        k_d = float(fixed["k_d"])
    else:
        with np.errstate(all="ignore"):
            f = p0 / np.maximum(abs_cos_o, 1e-6)
        k_d = diffuse_from_histogram(f[refl], histogram_bins)
    diffuse = np.where(~down, k_d / np.pi * abs_cos_o, 0.0)
    values = {"k_d": k_d}
    evaluations = 0
    for is_transmission, subset in ((False, refl), (True, trans)):
        lobes = [lb for lb in model.lobe_names() if lb[5] == is_transmission]
        if not lobes or not subset.any():
            defaults = {q.name: q.default for q in model.parameters}
            for lb in lobes:  # nothing to fit on this side: the lobe is off (k = 0), its shape the default
                values.update({name: fixed.get(name, 0.0 if j == 0 else defaults[name]) for j, name in enumerate(lb[:5])})
            continue
        g = lobe_geometry(wi[subset], wo[subset], is_transmission)
        ac = abs_cos_o[subset]
        specular = p0[subset] - diffuse[subset]
        contrib = [np.zeros(subset.sum()) for _ in lobes]
        found: list[dict[str, float] | None] = [None] * len(lobes)  # each lobe's values, once searched
        rounds = alternations if len(lobes) > 1 else 1
        for _ in range(rounds):
            for j, lb in enumerate(lobes):
                others = sum(contrib[:j] + contrib[j + 1:]) if len(lobes) > 1 else 0.0
                # with several lobes every target is clamped at 0 (§5.5): the first fit sees the specular part,
                # later ones the specular part minus the other lobes' current fits
                target = specular - others
                if len(lobes) > 1:
                    target = np.maximum(target, 0.0)
                box = {FIELDS[q]: tuple(search[name]) for q, name in enumerate(lb[:5]) if name in search}
                fix = {FIELDS[q]: fixed[name] for q, name in enumerate(lb[:5]) if name in fixed}
                res = search_lobe(g, ac, target, num[subset], is_transmission, n=n, iterations=iterations, box=box, fixed=fix)
                evaluations += res.evaluations
                found[j] = res.values
                contrib[j] = lobe_p(lb, res.values, g, ac)
        for lb, v in zip(lobes, found):
            assert v is not None, "every lobe is searched in the first round"
            values.update({name: v[FIELDS[q]] for q, name in enumerate(lb[:5])})
    params = {q.name: np.full((1, q.channels), values[q.name]) for q in model.parameters}
    return _finish(model, params, theta_i, theta_o, wi, wo, p, evaluations, time.perf_counter() - t0, k_d)


def _finish(model, params, theta_i, theta_o, wi, wo, p, evaluations, seconds, k_d, converged=True):
    pred = model.eval(params, wi[None], wo[None])[0, :, 0] * np.abs(wo[:, 2])
    down = wo[:, 2] < 0
    l1 = l1_error(p, pred, theta_i, theta_o)
    l1_r = l1_error(np.where(down, np.nan, p), pred, theta_i, theta_o)
    l1_t = l1_error(np.where(down, p, np.nan), pred, theta_i, theta_o)
    return TableFit(params, l1, l1_r, l1_t, evaluations, seconds, k_d, converged)


def refine_lm(model, start: TableFit, theta_i, theta_o, wi, wo, p, *, iterations=100, tolerance=1e-6, fixed=()) -> TableFit:
    """Levenberg–Marquardt from a grid result, on the same entries and weights as Eq 3.7 but squared.

    The residual of entry s is sqrt(sin θ_o |cos θ_i|)·|cos θ_o|·(f_model − f_meas): LM works in BSDF
    space (the contract's least-squares problem), the weight turns it into the metric's p-space.
    """
    from sbrdf_lib.lm import levenberg_marquardt

    t0 = time.perf_counter()
    p = np.asarray(p, float)
    use = np.isfinite(p) & (p != 0)
    ac = np.abs(wo[:, 2])
    num, _ = metric_weights(theta_i, theta_o)
    f = np.where(use & (ac > 1e-6), p / np.maximum(ac, 1e-6), 0.0)
    weight = np.where(use & (ac > 1e-6), np.sqrt(num) * ac, 0.0)
    form = model.fit_form()
    f3 = np.repeat(f[None, :, None], 3, axis=2)
    problem = form.least_squares(f3, weight[None], wi[None], wo[None])
    lo, hi = form.bounds()
    free = np.ones(form.size, bool)
    slices = form.slices()
    for name in fixed:
        key = name if name in slices else f"log_{name}"
        if key not in slices:
            raise ValueError(f"grid-search: fixed parameter {name!r} is not a parameter of {model.name}")
        free[slices[key]] = False
    x0 = np.clip(form.pack(form.from_model(start.params)), lo, hi)
    x, _, converged = levenberg_marquardt(problem, x0, (lo, hi), iterations=iterations, tolerance=tolerance, free=free)
    params = form.to_model(form.unpack(x))
    params = {k: np.asarray(v, float) for k, v in params.items()}
    out = _finish(model, params, theta_i, theta_o, wi, wo, p, start.evaluations, time.perf_counter() - t0, start.k_d,
                  bool(converged[0]))
    return out


class GridSearchFitter:
    """The ``grid-search`` fitter plugin: :func:`fit_table` per texel, optionally refined by LM."""

    model_name: str
    model_config: dict

    params = GRID_SEARCH

    # The dict defaults equal the declaration (the registry checks); they are copied, never changed.
    def __init__(self, *, model: str = "kurt-transmissive", model_params: dict = {}, n: int = 9,  # noqa: B006
                 iterations: int = 4, alternations: int = 2, search: dict = {}, fixed: dict = {},  # noqa: B006
                 histogram_bins: int = 64, lm_refine: bool = False, lm_iterations: int = 100):
        self.model_name, self.model_config = model, dict(model_params)
        self.n, self.iterations, self.alternations = n, iterations, alternations
        self.search, self.fixed, self.histogram_bins = dict(search), dict(fixed), histogram_bins
        self.lm_refine, self.lm_iterations = lm_refine, lm_iterations
        self.last: list[TableFit | None] = []  # per texel of the last fit; None: no valid sample

    @staticmethod
    def check_params(params):
        """Graph-load checks: search boxes are [low, high], and search/fixed name parameters of the configured model."""
        from .kurt import KurtTransmissiveModel

        problems = []
        try:
            known = {q.name for q in KurtTransmissiveModel(**dict(params.get("model_params") or {})).parameters}
        except (TypeError, ValueError):
            known = None  # the model's own parameter check reports a bad configuration
        for name in ("search", "fixed"):
            for key, value in dict(params.get(name) or {}).items():
                if known is not None and key not in known:
                    problems.append((name, f"{key!r} is not a parameter of kurt-transmissive with this "
                                           f"model_params; known: {', '.join(sorted(known))}"))
                elif name == "search" and not (isinstance(value, (list, tuple)) and len(value) == 2
                                               and float(value[0]) <= float(value[1])):
                    problems.append((name, f"{key}: give [low, high] with low <= high, got {value!r}"))
        return problems

    def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False,
            initial=None) -> FitResult:  # initial: no refinement from a given start here
        f_r, valid = usable_samples(f_r, valid)
        T = f_r.shape[0]
        params = model.defaults(T)
        flags = np.zeros(T, np.uint8)
        self.last = []
        for texel in range(T):
            use = valid[texel]
            if not use.any():
                self.last.append(None)
                continue
            w_i, w_o = wi[texel, use], wo[texel, use]
            p = f_r[texel, use].mean(axis=1) * np.abs(w_o[:, 2])
            theta_i = np.degrees(np.arccos(np.clip(np.abs(w_i[:, 2]), -1, 1)))
            theta_o = np.degrees(np.arccos(np.clip(w_o[:, 2], -1, 1)))
            res = fit_table(model, theta_i, theta_o, w_i, w_o, p, n=self.n, iterations=self.iterations,
                            alternations=self.alternations, search=self.search, fixed=self.fixed,
                            histogram_bins=self.histogram_bins)
            if self.lm_refine:
                res = refine_lm(model, res, theta_i, theta_o, w_i, w_o, p, iterations=self.lm_iterations,
                                fixed=tuple(self.fixed))
                if not res.converged:
                    flags[texel] |= NOT_CONVERGED
            self.last.append(res)
            for name, v in res.params.items():
                params[name][texel] = v[0]
        n = valid.sum(axis=1)
        logger.debug("grid search of %d texels: %d evaluations", T, sum(r.evaluations for r in self.last if r))
        return FitResult(params, rms_error(model, params, f_r, valid, wi, wo), n, flags)
