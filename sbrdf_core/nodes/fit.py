"""Fit: per-texel BRDF-model parameters from sampled reflectance.

The node streams over texel tiles (one chunk of SampledReflectance = all poses
of a tile), derives ω_i and ω_r per texel from the stored geometry, and calls
the fitter plugin on a flat batch of texels.  Around the fitter, for every
fitter alike, it makes the material trustworthy where it was not measured:

- **held-out error**: a seeded fraction of each texel's samples (``holdout``)
  is kept from the fitter and scored afterwards (``rms_holdout``); texels
  whose held-out RMS is far above their training RMS are flagged as overfit;
- **bounds**: each texel gets :class:`~sbrdf_core.constraints.Limits` (peak
  from its own and its neighbours' samples, sharpness from its sampling,
  albedo ≤ 1); fitters that take ``limits`` fit inside them, and whatever a
  fitter returns is projected onto them (:func:`~sbrdf_core.constraints.enforce`)
  and flagged if it moved;
- **sparse texels borrow**: a texel with fewer than ``min_samples`` valid
  samples is fitted to its own and its 3×3 neighbours' samples (a spatial
  prior) and flagged, rather than keeping the model defaults.

Fitter protocol: ``model_name`` and ``model_config`` attributes naming the
BRDF model to fit (the node constructs it from the registry), and
``fit(model, f_r, valid, wi, wo[, limits]) -> FitResult``.
"""

from __future__ import annotations

import functools
import logging
import time
import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .._compiled import worth_compiling
from ..artifacts import ParamMaps, SampledReflectance
from ..basis import MAX_MATERIALS, NO_LABEL
from ..brdf import evaluate
from ..channels import all_finite
from ..constraints import (
    REASONS,
    Limits,
    angular_resolution,
    enforce,
    neighbourhood_max,
    neighbourhood_min,
    sample_support,
)
from ..contracts import BRDFModel, Fitter, optional
from ..errors import SbrdfError
from ..geometry import tile_directions
from ..params import Param
from .base import BuildContext, NodeKind, Output, Port, shared

logger = logging.getLogger(__name__)


#: Bits of the ``flags`` map: why a texel's fit is missing or doubtful.  Stored
#: in the artifact's attributes too, so a reader needs no code to decode them.
FLAGS = {
    1: "no valid samples of its own: parameters borrowed from neighbours (flag 128) or the model defaults",
    2: "fewer valid samples than parameters: underdetermined, damped fit",
    4: "non-finite samples ignored",
    8: "iteration cap reached before convergence",
    16: "fitter produced non-finite values: parameters are the model defaults",
    32: "overfit: held-out RMS far above training RMS",
    64: "constrained: the unconstrained fit left the physical bounds (peak, sharpness or albedo)",
    128: "too few samples: fitted to its own and its neighbours' samples",
    256: "outlier: its appearance departs from its neighbourhood's, and no fit like its neighbours' fits its samples",
}
#: The ``material`` map's value for a texel without training samples (nothing to cluster).
MATERIAL_NONE = 255
NO_SAMPLES, UNDERDETERMINED, NONFINITE_INPUT, NOT_CONVERGED, NONFINITE_RESULT = 1, 2, 4, 8, 16
OVERFIT, CONSTRAINED, BORROWED, OUTLIER = 32, 64, 128, 256
#: Columns the kernel appends after the packed parameters.
EXTRA = ("rms", "rms_holdout", "samples", "flags", "restarted", "bounded_by", "fit_time_s", "from_neighbour",
         "material")


@dataclass(frozen=True)
class FitResult:
    """Per-texel fit output for a batch of T texels."""

    params: dict[str, np.ndarray]  # name -> (T, C), in the model's own form
    rms: np.ndarray | None  # (T,) sr^-1 over valid samples, RGB pooled; None when the caller passed rms=False
    samples: np.ndarray  # (T,) valid sample count
    flags: np.ndarray | None = None  # (T,) bits of FLAGS the fitter raised (e.g. NOT_CONVERGED)
    restarted: np.ndarray | None = None  # (T,) bool: the best result came from a later start (multi-start)


FIT_PARAMS = (
    Param("holdout", "float", 0.1, "fraction of each texel's valid samples kept from the fitter and scored as "
          "held-out RMS (0 = fit all, no held-out error); a texel with fewer than 2 × min_samples (16 when 0) "
          "keeps all, whatever the model, so fits of one scan are scored on the same samples", bounds=(0.0, 0.5)),
    Param("holdout_seed", "int", 0, "seed of the held-out split"),
    Param("peak_factor", "float", 4.0, "a texel's lobes may peak at most this times the largest sample of the texel "
          "and its 8 neighbours, anywhere on the hemisphere (0 = unbounded: warns)", bounds=(0.0, None)),
    Param("max_theta_deg", "float", 89.0, "the hemisphere the peak bound covers, degrees from the normal",
          bounds=(1.0, 89.99)),
    Param("albedo_limit", "float", 1.0, "directional albedo bound (energy conservation; 0 = off: warns)",
          bounds=(0.0, None)),
    Param("grazing_growth", "float", 0.0, "how much a lobe's shape may brighten from normal incidence toward grazing "
          "(Lafortune: max (C·ω)^n ≤ this; 1 = |C_x|, |C_y| ≤ C_z).  0 (default) = no such rule: real lobes rise "
          "toward grazing, and peak_factor still bounds them up to max_theta_deg", bounds=(0.0, None)),
    Param("resolve_sharpness", "bool", True, "bound exponents / roughness to what the angular sampling resolves"),
    Param("microfacet_peak", "str", "cosine", "what the peak bound holds for microfacet lobes (Cook-Torrance, "
          "Ward): 'cosine' = f_r cos θ_i cos θ_o, which keeps their 1/cos² rise toward grazing beyond the "
          "sampled range; 'f_r' = f_r itself, as for Lafortune, which forbids that rise and bends the fit "
          "where it was measured (docs/accuracy-vs-time.md measures both)", choices=("cosine", "f_r")),
    Param("min_samples", "int", 0, "texels with fewer valid samples are fitted with their neighbours' samples "
          "(0 = the model's parameter count)", bounds=(0, None)),
    Param("overfit_ratio", "float", 3.0, "flag a texel as overfit when its held-out RMS exceeds this times its "
          "training RMS", bounds=(1.0, None)),
    Param("coherence", "str", "neighbours", "'neighbours': a texel whose own solution fits its training samples "
          "clearly worse than a neighbour's solution is refitted from it (repeated, so a good solution spreads "
          "across a uniform region; removes the specks of texels caught in a worse local minimum, at the cost of "
          "refitting those texels); 'pyramid': the same, and each texel also tries its parent's solution "
          "from a coarse-to-fine fit of the tile's MIP pyramid of samples (about a third of a fit more); "
          "'basis': the tile's texels clustered into at most `materials` basis materials by appearance, each "
          "fitted from all its texels' samples, every texel refitted from its material's solution and keeping "
          "the lowest training cost of its own fit, the refit and the material's, then as 'neighbours'; writes "
          "the `material` label map (a tile's own labels; about 1.5-2x the time of 'neighbours': for uniform "
          "regions whose texels' own samples leave their fits loose); "
          "'none': every texel alone, as the fitter leaves it", choices=("neighbours", "pyramid", "basis", "none")),
    Param("outlier_distance", "float", 0.05, "with coherence: neighbours, a texel whose appearance (f_r at fixed "
          "direction pairs) departs from its 3x3 neighbourhood's median by more than this relative RMS is refitted "
          "from the neighbour nearest that median, and takes that fit if it fits its own samples within the noise; "
          "one that still departs is flagged an outlier (flag 256).  0 = neither", bounds=(0.0, None)),
    Param("materials", "int", 4, "with coherence: basis, the basis materials (clusters) per tile; 0 = as many as "
          f"keep paying (another while it halves the clusters' spread, at most {MAX_MATERIALS})",
          bounds=(0, MAX_MATERIALS)),
)


#: The declared defaults, which FitOptions and the relaxed-bound check take from FIT_PARAMS.
DEFAULTS = {p.name: p.default for p in FIT_PARAMS}
#: Node parameters that bound the fit: 0 / false turns one off, a larger value loosens it (both warn).
BOUNDS = ("peak_factor", "albedo_limit", "grazing_growth", "resolve_sharpness")


@dataclass(frozen=True)
class FitOptions:
    """The node's own parameters, as the kernel uses them (declared in :data:`FIT_PARAMS`)."""

    holdout: float = DEFAULTS["holdout"]
    holdout_seed: int = DEFAULTS["holdout_seed"]
    peak_factor: float = DEFAULTS["peak_factor"]
    max_theta_deg: float = DEFAULTS["max_theta_deg"]
    albedo_limit: float = DEFAULTS["albedo_limit"]
    resolve_sharpness: bool = DEFAULTS["resolve_sharpness"]
    min_samples: int = DEFAULTS["min_samples"]
    overfit_ratio: float = DEFAULTS["overfit_ratio"]
    grazing_growth: float = DEFAULTS["grazing_growth"]
    microfacet_peak: str = DEFAULTS["microfacet_peak"]
    coherence: str = DEFAULTS["coherence"]
    outlier_distance: float = DEFAULTS["outlier_distance"]
    materials: int = DEFAULTS["materials"]

    def limits(self, support: np.ndarray, resolution: np.ndarray, support_cosine: np.ndarray | None = None) -> Limits:
        on = self.peak_factor > 0
        return Limits(peak=self.peak_factor * support if on else None,
                      peak_cosine=self.peak_factor * support_cosine
                      if on and support_cosine is not None and self.microfacet_peak == "cosine" else None,
                      resolution=resolution if self.resolve_sharpness else None,
                      max_theta=float(np.radians(self.max_theta_deg)),
                      albedo=self.albedo_limit if self.albedo_limit > 0 else None,
                      growth=self.grazing_growth if self.grazing_growth > 0 else None)


def usable(f_r: np.ndarray, valid: np.ndarray, dtype=None) -> tuple[np.ndarray, np.ndarray]:
    """``(f_r, valid)`` with non-finite samples invalid and every invalid sample 0 (``f_r`` as ``dtype``, default
    its own).

    Fitters call this first: invalid samples may carry anything (NaN from a
    broken pixel, garbage from a saturated one) and weights of 0 do not stop
    NaN from propagating through ``0 · NaN``.
    """
    f_r, valid = np.asarray(f_r), np.asarray(valid)
    dtype = f_r.dtype if dtype is None else np.dtype(dtype)
    compiled_types = (np.float32, np.float64)  # what numba compiles (float16 and longdouble: NumPy below)
    if (worth_compiling(f_r.size) and f_r.ndim == 3 and valid.shape == f_r.shape[:2] and f_r.dtype in compiled_types
            and dtype in compiled_types):
        # One pass for the test, the conversion and the copy, the same bits as the NumPy passes below
        # (tests/core/test_usable.py).
        out = np.empty(f_r.shape, dtype)
        return out, _compiled_usable()(f_r, valid.astype(bool, copy=False), out)
    valid = usable_mask(f_r, valid)
    return np.where(valid[..., None], f_r.astype(dtype, copy=False), dtype.type(0)), valid


@functools.cache
def _compiled_usable():
    """:func:`usable`'s kernel (numba, cached on disk): fills ``out`` and returns the mask.  Why: the NumPy
    passes (a finiteness test per channel, then a copy) ran twice a Fit tile, a twentieth of a Lafortune one."""
    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(f_r, valid, out):  # pragma: no cover (compiled)
        T, S, C = f_r.shape
        mask = np.empty((T, S), np.bool_)
        for t in range(T):
            for s in range(S):
                ok = valid[t, s]
                for c in range(C):
                    ok = ok and np.isfinite(f_r[t, s, c])
                mask[t, s] = ok
                for c in range(C):
                    out[t, s, c] = f_r[t, s, c] if ok else 0.0
        return mask

    return kernel


def usable_mask(f_r: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The ``valid`` of :func:`usable` without its copy of ``f_r``: a tenth of the cost, for a fitter that only
    counts the usable samples and hands the rest to code that calls :func:`usable` itself."""
    return np.asarray(valid, bool) & all_finite(f_r)


def rms_error(model, params, f_r, valid, wi, wo) -> np.ndarray:
    """RMS of ``model − f_r`` over each texel's valid samples and RGB pooled (seed 000 §4.4), sr⁻¹."""
    with np.errstate(all="ignore"):
        return masked_rms(evaluate(model, params, wi, wo) - f_r, valid)


def masked_rms(diff: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """RMS of residuals ``(T, S, C)`` over each texel's samples in ``mask`` and the channels (0 with none)."""
    return squares_rms(sample_squares(diff), mask, diff.shape[-1])


def residual_squares(model, params, wi, wo, f_r) -> np.ndarray:
    """:func:`sample_squares` of ``model.eval − f_r``, ``(T, S)`` (compiled where the model has a fit kernel)."""
    with np.errstate(all="ignore"):
        return sample_squares(evaluate(model, params, wi, wo) - f_r)


def sample_squares(diff: np.ndarray) -> np.ndarray:
    """Each sample's sum of squared residuals over the channels, ``(T, S)``: what :func:`squares_rms` reads, made
    once for several masks (the Fit node's training and held-out samples)."""
    out = diff[..., 0] * diff[..., 0]
    for c in range(1, diff.shape[-1]):
        out += diff[..., c] * diff[..., c]
    return out


def squares_rms(squares: np.ndarray, mask: np.ndarray, channels: int) -> np.ndarray:
    """:func:`masked_rms` from :func:`sample_squares` (a NaN outside ``mask`` does not count)."""
    return np.sqrt(np.where(mask, squares, 0.0).sum(axis=1) / np.maximum(mask.sum(axis=1) * channels, 1))


#: Training samples a texel keeps at least for any sample to be held out from it (where ``min_samples`` is 0):
#: a count, not the model's parameter count, so the split is the same for every model.
HOLDOUT_MIN_TRAIN = 8


def holdout_split(valid: np.ndarray, fraction: float, seed: int, offset: tuple[int, int], min_train: int,
                  skip: int = 0):
    """``(train, test)`` masks: a seeded ``fraction`` of each texel's valid samples held out.

    Seeded by the tile's position, so a tile gives the same split on every run
    and on any worker.  A texel keeps all its samples for training when
    holding some out would leave it fewer than ``2 · min_train``.  ``skip``
    draws of the tile's stream are passed over first: a task fitting rows of a
    tile (:func:`fit_block`) gets the same split as the whole tile would.
    """
    if fraction <= 0:
        return valid, np.zeros_like(valid)
    bits = np.random.PCG64([seed, *offset])  # default_rng's generator, named: advance is PCG64's
    if skip:
        bits.advance(skip)  # one 64-bit draw per double
    rng = np.random.Generator(bits)
    test = valid & (rng.random(valid.shape) < fraction)
    enough = valid.sum(axis=1) >= 2 * max(min_train, 1)
    test &= enough[:, None]
    return valid & ~test, test


def _neighbour_pool(grid: tuple[int, int], texels: np.ndarray, *arrays):
    """Concatenate each listed texel's samples with its in-tile 3×3 neighbours' along the sample axis."""
    V, U = grid
    v, u = np.divmod(texels, U)
    out = []
    for a in arrays:
        a = a.reshape((V, U) + a.shape[1:])
        pad = np.pad(a, [(1, 1), (1, 1)] + [(0, 0)] * (a.ndim - 2))
        parts = [pad[v + 1 + dv, u + 1 + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)]
        out.append(np.concatenate(parts, axis=1))
    return out


def fit_tile(f_r, valid, light_pos, camera_pos, texels, size_mm, fitter: Fitter, model: BRDFModel,
             options=FitOptions(), block_info=None,
             holdout_at: tuple[tuple[int, int], int] | None = None, start: tuple | None = None):
    """Kernel: a ``(v, u, P, 3)`` tile -> ``(v, u, K + len(EXTRA))`` = packed parameters and :data:`EXTRA`.

    Non-finite samples are dropped before the fitter sees them, and whatever
    the fitter returns, no NaN or inf reaches the parameter maps: such texels
    get the model's defaults and a flag saying why.  ``rms_holdout`` is NaN
    where a texel had no held-out sample.  ``holdout_at`` = ``(tile origin, draws to skip)`` seeds the
    held-out split of a block that is part of a stored tile (:func:`_fit_rows`).  ``start`` =
    ``(start model, {parameter: stored map})``: the ``start`` input's maps, read at this block (:func:`keep_start`).
    """
    t0 = time.perf_counter()
    (v0, v1), (u0, u1) = block_info[0]["array-location"][:2]
    grid = (v1 - v0, u1 - u0)
    wi, _, wo = tile_directions(texels, size_mm, (v0, v1), (u0, u1), light_pos, camera_pos)
    T = wi.shape[0]
    given = valid.reshape(T, -1)
    f_r, valid = usable(f_r.reshape(T, -1, 3), given, np.float64)
    flags = np.where((given & ~valid).any(axis=1), NONFINITE_INPUT, 0).astype(np.uint16)
    min_samples = options.min_samples or model.size
    support = neighbourhood_max(sample_support(f_r, valid).reshape(grid)).ravel()
    origin, skip = holdout_at if holdout_at is not None else ((v0, u0), 0)
    # the split reads no model: fits of one scan with different models (Select, a start) see the same samples
    train, test = holdout_split(valid, options.holdout, options.holdout_seed, origin,
                                options.min_samples or HOLDOUT_MIN_TRAIN, skip)
    resolution = angular_resolution(wi, wo, train)
    sparse = np.flatnonzero(train.sum(axis=1) < min_samples)
    if sparse.size:  # fitted to the pooled samples: bounded by what the pool resolves
        pf, pw, pi, po = _neighbour_pool(grid, sparse, f_r, train, wi, wo)
        resolution[sparse] = angular_resolution(pi, po, pw)
    resolution = neighbourhood_min(resolution.reshape(grid)).ravel()
    support_cosine = None
    if options.microfacet_peak == "cosine" and optional(model, "reads_peak_cosine", "brdf-model"):
        cosines = np.clip(wi[..., 2], 0, 1) * np.clip(wo[..., 2], 0, 1)
        support_cosine = neighbourhood_max(sample_support(f_r, valid, cosines).reshape(grid)).ravel()
    limits = options.limits(support, resolution, support_cosine)

    def run(f, w, a, b, lim, initial=None):
        # rms=False: the node scores the fit itself, below; usable=True: f, w are usable()'s (the pool's too)
        if initial is None:  # a fitter written before `initial` need not take it (Fit.options turns coherence off)
            return fitter.fit(model, f, w, a, b, limits=lim, rms=False, usable=True)
        return fitter.fit(model, f, w, a, b, limits=lim, rms=False, usable=True, initial=initial)

    res: FitResult = run(f_r, train, wi, wo, limits)
    params = {k: np.array(v, dtype=np.float64) for k, v in res.params.items()}
    rflags = np.zeros(T, np.uint16) if res.flags is None else res.flags.astype(np.uint16)
    restarted = np.zeros(T, bool) if res.restarted is None else np.asarray(res.restarted, bool)
    if sparse.size:
        pooled = run(pf, pw, pi, po, limits.take(sparse))
        helped = pw.sum(axis=1) > train[sparse].sum(axis=1)
        for k, v in pooled.params.items():
            params[k][sparse[helped]] = np.asarray(v)[helped]
        rflags[sparse[helped]] = 0 if pooled.flags is None else pooled.flags[helped]
        flags[sparse[helped]] |= BORROWED
    from_neighbour = np.zeros(T, bool)
    material = np.full(T, NO_LABEL)

    cleared: set = set()  # solutions the energy bound holds already: it need not integrate them again

    def project(rows, x):
        return model.pack(enforce(model, model.unpack(x), limits.take(rows), cleared=cleared)[0])

    if options.coherence != "none" and (T > 1 or options.coherence == "basis"):  # a lone texel has a label
        from ..basis import basis
        from ..coherence import APPEARANCE_PAIRS, cohere, pyramid  # the kernel's work, not the node's listing

        def refit(rows, initial, prior):
            # the prior's samples (the neighbourhood's median appearance) ride along where given
            pw, po = (np.broadcast_to(w, (rows.size,) + w.shape[1:]) for w in APPEARANCE_PAIRS)
            use = np.broadcast_to(np.isfinite(prior).all(axis=-1), prior.shape[:2])
            out = run(np.concatenate([f_r[rows], np.where(use[..., None], prior, 0.0)], axis=1),
                      np.concatenate([train[rows], use], axis=1), np.concatenate([wi[rows], pw], axis=1),
                      np.concatenate([wo[rows], po], axis=1), limits.take(rows), initial)
            rflags[rows] = 0 if out.flags is None else out.flags
            return packed(out)

        def packed(out: FitResult) -> np.ndarray:
            return model.pack({k: np.asarray(v, np.float64) for k, v in out.params.items()})

        def coarse(f, w, a, b, lim, initial):
            return packed(run(f, w, a, b, lim, None if initial is None else model.unpack(initial)))

        x = model.pack(params)
        if options.coherence == "basis":
            refit_flags = np.zeros(T, np.uint16)

            def own_refit(rows, initial):
                out = run(f_r[rows], train[rows], wi[rows], wo[rows], limits.take(rows), initial)
                refit_flags[rows] = 0 if out.flags is None else out.flags
                return packed(out)

            def cluster_fit(f, w, a, b, rows, initial):
                return coarse(f, w, a, b, limits.take(rows), initial)

            x, material, from_basis, refitted = basis(model, x, f_r, train, wi, wo, options.materials, cluster_fit,
                                                      own_refit, project)
            rflags[refitted] = refit_flags[refitted]
        parent = pyramid(coarse, f_r, train, wi, wo, grid, limits) if options.coherence == "pyramid" else None
        x, from_neighbour, outlier = cohere(model, x, f_r, train, wi, wo, grid, refit,
                                            options.outlier_distance, parent=parent, project=project)
        if options.coherence == "basis":
            from_neighbour |= from_basis
        params = model.unpack(x)
        flags |= np.where(outlier, OUTLIER, 0).astype(np.uint16)
    if start is not None:
        start_model, maps = start
        given = read_start(model, start_model, maps, (slice(v0, v1), slice(u0, u1)))
        params = keep_start(model, params, given, f_r, train, wi, wo, project)
    params, changed, bounded_by = enforce(model, params, limits, why=True, cleared=cleared)
    flags |= rflags | np.where(changed, CONSTRAINED, 0).astype(np.uint16)
    # The errors are those of the parameters as stored (float32): a residual a hundredth of f_r turns their
    # rounding into parts in 10⁶ of the RMS, enough to rank two fits of equal parameters apart.
    with np.errstate(over="ignore"):
        x = model.pack(params).astype(np.float32).astype(np.float64)
    params = model.unpack(x)
    squares = residual_squares(model, params, wi, wo, f_r)  # one evaluation for both errors
    rms = squares_rms(squares, train, f_r.shape[-1])
    rms_holdout = np.where(test.any(axis=1), squares_rms(squares, test, f_r.shape[-1]), np.nan)
    own = valid.sum(axis=1)
    bad = ~(np.isfinite(x).all(axis=1) & np.isfinite(rms))
    empty = (own == 0) & ~((flags & BORROWED) > 0)
    flags |= np.where(bad, NONFINITE_RESULT, 0).astype(np.uint16) | np.where(own == 0, NO_SAMPLES, 0).astype(np.uint16)
    flags |= np.where((own > 0) & (own * 3 < model.size), UNDERDETERMINED, 0).astype(np.uint16)
    with np.errstate(invalid="ignore"):
        overfit = rms_holdout > options.overfit_ratio * np.maximum(rms, 1e-3 * support + 1e-9)
    flags |= np.where(overfit, OVERFIT, 0).astype(np.uint16)
    x[bad | empty] = model.pack(model.defaults(1))[0]
    rms = np.where(bad | empty, 0.0, rms)
    rms_holdout = np.where(bad | empty, np.nan, rms_holdout)
    seconds = np.full(T, (time.perf_counter() - t0) / T)
    logger.debug("fit tile of %d texels with %s: %.3f s, %d flagged", T, type(fitter).__name__, seconds.sum(),
                  int((flags != 0).sum()))
    out = np.concatenate([x, np.stack([rms, rms_holdout, own, flags, restarted, bounded_by, seconds, from_neighbour,
                                       material], axis=1)], axis=1)
    return out.reshape(grid + (-1,)).astype(np.float32)


def start_embedding(model: BRDFModel, start: BRDFModel):
    """Packed rows of ``start``'s parameters -> packed rows of ``model``, or None where ``start`` is neither
    ``model`` (the same parameters) nor a model its fit form contains through ``nested()``, once or more (a
    1-lobe Lafortune in a 3-lobe one): the smaller model's solution with the extra parts dead."""
    if start.name == model.name and [p.name for p in start.parameters] == [p.name for p in model.parameters]:
        return lambda x: x
    form: Any = model.fit_form()  # the contract's BRDFModel lists no fit-form conversions
    nested = optional(form, "nested", "brdf-model")
    inner = nested() if nested is not None else None
    if inner is None:
        return None
    smaller, embed = inner
    below = start_embedding(smaller, start)
    if below is None:
        return None
    sform: Any = smaller.fit_form()
    return lambda x: model.pack(form.to_model(form.unpack(embed(sform.pack(sform.from_model(smaller.unpack(below(x))))))))


def read_start(model: BRDFModel, start_model: BRDFModel, maps: dict, where: tuple[slice, slice]) -> np.ndarray:
    """``(T, K)``: the ``start`` input's maps at ``where`` (rows, columns), as packed rows of ``model``."""
    x = start_model.pack({p.name: maps[p.name][where] for p in start_model.parameters})
    embed = start_embedding(model, start_model)
    assert embed is not None  # Fit.build refused any other start
    return embed(x)


def keep_start(model: BRDFModel, params: dict, start: np.ndarray, f_r, train, wi, wo, project) -> dict:
    """``params`` with each texel's solution replaced by ``start``'s (``(T, K)`` packed) where that fits the
    texel's training samples better, both as they will leave the node (``project``ed onto its bounds).

    Why: two Fit nodes search apart (their coherence sweeps take different neighbours' solutions), so a
    2-lobe fit alone can end above a 1-lobe fit of the same samples on a few texels; given the 1-lobe maps
    as its ``start``, it never does.
    """
    from ..coherence import training_costs

    x = model.pack(params)
    rows = np.flatnonzero(np.isfinite(start).all(axis=1) & train.any(axis=1))
    if rows.size == 0:
        return params
    mine, theirs = project(rows, x[rows]), project(rows, start[rows])
    cost_of = training_costs(model, f_r, train, wi, wo)
    c_mine, c_theirs = cost_of(mine, rows), cost_of(theirs, rows)
    take = np.isfinite(c_theirs) & ~(c_mine <= c_theirs)
    x[rows] = np.where(take[:, None], theirs, mine)
    return model.unpack(x)


#: Working memory of one Fit task (a tile and its fit), from which its texels are chosen: a budget in
#: bytes, not a fixed tile, so a task holds the same bytes whatever the number of poses.
FIT_TASK_BYTES = 96 * 2**20
#: Bytes per sample (a texel's pose) one Fit task holds: the node's float64 copies of f_r, ω_i, ω_o and the
#: residuals, plus the fitter's work (measured with tracemalloc: the lm fitter's generic LM of Lambert about
#: 340, its compiled Lafortune kernels about 190).
FIT_SAMPLE_BYTES = 320


def fit_block(poses: int, tile: tuple[int, int], budget: int | None = None) -> int:
    """Rows of a stored tile per Fit task: all of them, or fewer when the tile's samples are over ``budget``.

    Reflectance stores tiles whose bytes only roughly track the poses (power-of-two edges, DESIGN.md), and
    a Fit task's memory is many times a sample's stored bytes, so the node fits a tile in strips of whole
    rows whose samples fit the budget (default :data:`FIT_TASK_BYTES`): memory per task stays within one
    row's samples of the budget from small scans to large ones.  A strip is fitted as the whole tile fits
    those rows (:func:`_fit_rows`), so scans whose tiles fit the budget and those whose tiles do not get
    the same maps (for fitters that fit texels independently, as ``lm`` does).
    """
    rows, cols = tile
    samples = max(1, (FIT_TASK_BYTES if budget is None else budget) // FIT_SAMPLE_BYTES)
    return int(min(rows, max(1, samples // (max(cols, 1) * max(poses, 1)))))


def _fit_rows(grid, f_r, valid, light_pos, camera_pos, texels, size_mm, fitter: Fitter, model: BRDFModel, options,
              tile, start=None, block_info=None) -> np.ndarray:
    """Kernel: rows ``v0:v1`` of a stored tile -> what :func:`fit_tile` gives those rows of the whole tile.

    Reads the rows and one more on each side within the tile (the 3×3 neighbourhood bounds and the
    borrowing of sparse texels see the neighbours the whole tile would) and seeds the held-out split
    with the tile's stream at these rows.  The side rows are fitted too and dropped.
    """
    (v0, v1), (u0, u1) = block_info[None]["array-location"][:2]
    tile_v0 = v0 - v0 % tile[0]
    e0, e1 = max(tile_v0, v0 - 1), min(tile_v0 + tile[0], f_r.shape[0], v1 + 1)
    P = f_r.shape[2]
    info = {0: {"array-location": [(e0, e1), (u0, u1), (0, P), (0, 3)]}}
    out = fit_tile(f_r[e0:e1, u0:u1], valid[e0:e1, u0:u1][..., None], light_pos, camera_pos, texels, size_mm, fitter,
                   model, options, block_info=info, holdout_at=((tile_v0, u0), (e0 - tile_v0) * (u1 - u0) * P),
                   start=start)
    return out[v0 - e0:v1 - e0]


def _within(n: int, tile: int, part: int) -> tuple[int, ...]:
    """Chunk sizes along an axis of ``n`` stored in ``tile``-sized chunks, each split into parts of ``part``:
    no task's part crosses a stored tile."""
    out: list[int] = []
    for start in range(0, n, tile):
        size = min(tile, n - start)
        out += [part] * (size // part) + ([size % part] if size % part else [])
    return tuple(out)


def takes_initial(fitter) -> bool:
    """Whether ``fitter.fit`` accepts ``initial`` (a fitter written before the keyword need not): read once, when
    the node is built."""
    import inspect

    params = inspect.signature(fitter.fit).parameters
    return "initial" in params or any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())


class Fit(NodeKind):
    name = "Fit"
    doc = ("Fit a BRDF model per texel inside its physical bounds; writes parameter maps, training and held-out "
           "RMS maps, sample counts and flags.")
    inputs = (Port("samples", (SampledReflectance,), "sampled reflectance (a single BRDF is a 1x1 grid)"),
              Port("start", (ParamMaps,), "a fit of the same samples with this model or one it contains (fewer "
                   "Lafortune lobes): each texel keeps whichever of its own fit and that one fits its training "
                   "samples better, so a larger model never ends above the smaller one", optional=True))
    output = ParamMaps
    plugin_category = "fitter"
    params = FIT_PARAMS

    @classmethod
    def model(cls, ctx: BuildContext):
        return ctx.plugins().create("brdf-model", ctx.plugin.model_name, dict(ctx.plugin.model_config))

    @classmethod
    def options(cls, ctx: BuildContext) -> FitOptions:
        """The node parameters; relaxing a physical bound is allowed, and said."""
        opts = FitOptions(**{p.name: ctx.params.get(p.name, p.default) for p in FIT_PARAMS})
        relaxed = [f"{name}: {getattr(opts, name)}" for name in BOUNDS
                   if DEFAULTS[name] and (not getattr(opts, name) or getattr(opts, name) > DEFAULTS[name])]
        if relaxed:
            warnings.warn(f"node {ctx.node!r}: physical bounds relaxed ({', '.join(relaxed)}): fitted lobes may "
                          "exceed what the samples support where they were not measured", stacklevel=2)
        if opts.coherence != "none" and not takes_initial(ctx.plugin):
            warnings.warn(f"node {ctx.node!r}: fitter {type(ctx.plugin).__name__} takes no `initial` keyword (the "
                          "fitter contract's refinement from a given solution): coherence is off for this node",
                          stacklevel=2)
            opts = replace(opts, coherence="none")
        return opts

    @classmethod
    def start(cls, ctx: BuildContext, model: BRDFModel, samples):
        """The ``start`` input as :func:`fit_tile` reads it (its model and stored maps, one graph key), or None;
        a start of another model or another grid is refused with both named."""
        given = ctx.inputs.get("start")
        if given is None:
            return None
        start_model = ctx.plugins().create("brdf-model", given.attrs["model"], dict(given.attrs.get("model_config", {})))
        if start_embedding(model, start_model) is None:
            raise SbrdfError(f"node {ctx.node!r}: its start fitted {start_model.name} "
                             f"{given.attrs.get('model_config', {})}, which {model.name} {dict(ctx.plugin.model_config)} "
                             "does not contain: start from a fit of the same model or of fewer lobes")
        if list(given.attrs["texels"]) != list(samples.attrs["texels"]):
            raise SbrdfError(f"node {ctx.node!r}: its start has {list(given.attrs['texels'])} texels, its samples "
                             f"{list(samples.attrs['texels'])}: start from a fit of the same samples")
        return shared((start_model, {p.name: given.zarr_array(f"params/{p.name}") for p in start_model.parameters}))

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        samples = ctx.inputs["samples"]
        model = cls.model(ctx)
        options = cls.options(ctx)
        f_r, valid = samples.array("f_r"), samples.array("valid")
        K = model.size
        tile = (f_r.chunks[0][0], f_r.chunks[1][0])
        rows = fit_block(f_r.shape[2], tile)
        start = cls.start(ctx, model, samples)
        if rows >= tile[0]:  # a stored tile per task
            packed = da.map_blocks(
                fit_tile, f_r, valid[..., None], samples.read("light_pos"), samples.read("camera_pos"),
                tuple(samples.attrs["texels"]), tuple(samples.attrs["size_mm"]), ctx.plugin, model, options,
                start=start, drop_axis=[3], chunks=f_r.chunks[:2] + ((K + len(EXTRA),),), dtype=np.float32,
                name=ctx.key("fit"),
            )
        else:  # rows of a tile per task, read by the task (tile chunks would be held while their parts wait)
            V, U = f_r.shape[:2]
            grid = da.zeros((V, U), chunks=(_within(V, tile[0], rows), f_r.chunks[1]), dtype=np.uint8)
            packed = da.map_blocks(
                _fit_rows, grid, shared(samples.zarr_array("f_r")), shared(samples.zarr_array("valid")),
                shared(samples.read("light_pos")), shared(samples.read("camera_pos")),
                tuple(samples.attrs["texels"]), tuple(samples.attrs["size_mm"]), ctx.plugin, model, options, tile,
                start, new_axis=[2], chunks=grid.chunks + ((K + len(EXTRA),),), dtype=np.float32, name=ctx.key("fit"),
            )
        arrays = {f"params/{name}": packed[..., s] for name, s in model.slices().items()}
        column = {name: packed[..., K + i] for i, name in enumerate(EXTRA)}
        arrays["rms"] = column["rms"]
        arrays["rms_holdout"] = column["rms_holdout"]
        arrays["samples"] = column["samples"].astype(np.int32)
        arrays["flags"] = column["flags"].astype(np.uint16)
        arrays["restarted"] = column["restarted"].astype(np.uint8)
        arrays["bounded_by"] = column["bounded_by"].astype(np.uint8)
        arrays["fit_time_s"] = column["fit_time_s"]
        arrays["from_neighbour"] = column["from_neighbour"].astype(np.uint8)
        if options.coherence == "basis":  # labels of the tile's own clusters; none: no samples to cluster
            arrays["material"] = da.where(column["material"] < 0, MATERIAL_NONE, column["material"]).astype(np.uint8)
        return Output(
            arrays=arrays,
            attrs={
                "fitter": ctx.spec.name if ctx.spec else None,
                "flag_bits": {str(b): text for b, text in FLAGS.items()},
                "bounded_by_bits": {str(b): text for b, text in REASONS.items()},
                "model": model.name,
                "model_config": dict(ctx.plugin.model_config),
                "parameters": model.describe(),
                "texels": samples.attrs["texels"],
                "size_mm": samples.attrs["size_mm"],
                "bounds": {"peak_factor": options.peak_factor, "max_theta_deg": options.max_theta_deg,
                           "albedo_limit": options.albedo_limit, "resolve_sharpness": options.resolve_sharpness,
                           "grazing_growth": options.grazing_growth, "microfacet_peak": options.microfacet_peak},
                "holdout": options.holdout,
                "coherence": options.coherence,
            },
            finalize=summarize,
        )


def summarize(art) -> dict:
    """The ``summary`` attribute: training and held-out error, and how many texels each flag marks."""
    rms, n, flags = art.read("rms"), art.read("samples"), art.read("flags")
    held = art.read("rms_holdout") if "rms_holdout" in art.names() else np.full(rms.shape, np.nan)
    restarted = art.read("restarted") if "restarted" in art.names() else np.zeros(rms.shape, np.uint8)
    bounded = art.read("bounded_by") if "bounded_by" in art.names() else np.zeros(rms.shape, np.uint8)
    fitted = (n > 0) | ((flags & BORROWED) > 0)
    labels = art.read("material") if "material" in art.names() else None
    # a tile's labels are its own: the count is the most materials a tile has, not a count across tiles
    materials = {} if labels is None else {"materials": int(labels[labels != MATERIAL_NONE].max(initial=0)) + 1
                                           if (labels != MATERIAL_NONE).any() else 0}
    scored = fitted & np.isfinite(held)
    stat = lambda a, m, f: float(f(a[m])) if m.any() else None  # noqa: E731
    return {"summary": {
        **materials,  # first: `sbrdf info` shows the summary's first 200 characters
        "rms_mean": stat(rms, fitted, np.mean),
        "rms_max": stat(rms, fitted, np.max),
        "rms_p95": stat(rms, fitted, lambda a: np.percentile(a, 95)),
        "rms_holdout_mean": stat(held, scored, np.mean),
        "rms_holdout_p95": stat(held, scored, lambda a: np.percentile(a, 95)),
        "fit_time_s": float(art.read("fit_time_s").astype(np.float64).sum()),
        "texels_without_samples": int((n == 0).sum()),
        "texels_flagged_any": int((flags > 0).sum()),
        "restart_won_fraction": float((restarted > 0).mean()) if restarted.size else 0.0,
        "from_neighbour_fraction": float((art.read("from_neighbour") > 0).mean())
        if "from_neighbour" in art.names() else 0.0,
        "texels_flagged": {FLAGS[b]: int(((flags & b) > 0).sum()) for b in FLAGS if ((flags & b) > 0).any()},
        "texels_bounded_by": {REASONS[b]: int(((bounded & b) > 0).sum()) for b in REASONS if ((bounded & b) > 0).any()},
    }}
