"""Camera response curves: model them, recover them from exposure brackets, invert them.

Cameras do not store linear sensor values: a response curve maps the
exposure (radiance × time) to a pixel code (seed 000 §3.4.1).  Reflectance
needs linear radiance, so every LDR image goes through the *inverse* response
``g: code -> relative exposure`` before anything else.

Here a curve is a table ``g`` with one entry per code (256 or 65536),
normalised so that ``g(max code) = 1``: relative exposure 1 is the
saturation point.  That is also the ``{"type": "table"}`` form of the
capture-folder manifest.  The table models and :class:`ResponseCurve` live in
:mod:`sbrdf_lib.response` (simulated cameras use them too) and are re-exported
here; this module adds recovery.

Two recovery methods, as in the thesis:

- :func:`recover_cubic_loglog`: McAllister's cubic in log-log space,
  ``log X = a3 (log z)^3 + a2 (log z)^2 + a1 log z`` per channel (``z`` the
  code normalised to (0, 1]; no constant term so that ``z = 1 <=> X = 1``).
  He fitted it to measurements with known relative exposures (ND filters,
  :func:`fit_cubic_loglog`); from brackets of unknown scenes the unknown
  per-pixel radiances enter linearly in log space, so the joint fit is still
  one small linear least-squares problem (the radiances are eliminated by
  centring each pixel's equations).
- :func:`recover_debevec`: Debevec & Malik 1997, 8-bit only, defined up
  to a scale factor (fixed here by ``g(reference code) = 1``; compare curves
  with ``fit_scale=True``).  Brackets that all share one set of exposure
  times go through OpenCV's ``cv2.createCalibrateDebevec``; brackets of
  different times (or lengths) per pose, as the exposure planner makes
  them, through the same least-squares system solved here, where every
  sample carries its own Δt (:func:`solve_debevec`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sbrdf_lib.response import ResponseCurve, ResponseError, codes, cubic_table, gamma_table, response_table, srgb_table

__all__ = ["ResponseCurve", "ResponseError", "bracket_samples", "codes", "cubic_curve", "cubic_table",
           "fit_cubic_loglog", "gamma_table", "recover_cubic_loglog", "recover_debevec", "relative_error",
           "response_table", "solve_debevec", "srgb_table"]


def relative_error(recovered: np.ndarray, truth: np.ndarray, lo: float = 0.1, hi: float = 0.9,
                   fit_scale: bool = False) -> float:
    """Max relative error of ``recovered`` against ``truth`` over codes ``lo·max .. hi·max``.

    With ``fit_scale`` the recovered curve is first scaled by the least-squares
    factor in log space (Debevec's curves are defined up to scale).
    """
    rec = np.asarray(recovered, np.float64).reshape(len(truth), -1)
    tru = np.asarray(truth, np.float64).reshape(len(truth), -1)
    z = codes(8 if len(truth) == 256 else 16)
    mid = (z >= lo) & (z <= hi)
    if fit_scale:
        rec = rec * np.exp(np.mean(np.log(tru[mid]) - np.log(np.maximum(rec[mid], 1e-300)), axis=0))
    return float(np.max(np.abs(rec[mid] / tru[mid] - 1.0)))


# ---------------------------------------------------------------------------
# recovery
# ---------------------------------------------------------------------------


def fit_cubic_loglog(pixel_codes: np.ndarray, relative_exposure: np.ndarray, max_code: int) -> np.ndarray:
    """McAllister's calibration: known relative exposures (ND filters × time) -> cubic coefficients.

    ``pixel_codes`` and ``relative_exposure`` are 1-D (one channel), exposure
    normalised so the saturation point is 1.  Returns ``[a1, a2, a3]``.
    """
    z = np.asarray(pixel_codes, np.float64) / max_code
    x = np.asarray(relative_exposure, np.float64)
    keep = (z > 0) & (z < 1) & (x > 0)
    if keep.sum() < 3:
        raise ResponseError(f"a cubic fit needs at least 3 unsaturated, non-black measurements, got {int(keep.sum())}")
    y = np.log(z[keep])
    A = np.stack([y, y**2, y**3], axis=1)
    coef, *_ = np.linalg.lstsq(A, np.log(x[keep]), rcond=None)
    return coef


def recover_cubic_loglog(samples: np.ndarray, times: np.ndarray, max_code: int,
                         low: float = 0.02, high: float = 0.98) -> np.ndarray:
    """Cubic log-log response per channel from bracketed pixel samples of unknown radiance.

    Parameters
    ----------
    samples
        ``(J, K, 3)`` integer codes: J scene points each photographed at K exposures.
    times
        ``(J, K)`` or ``(K,)`` exposure times, s.
    low, high
        Codes outside ``(low, high) · max_code`` (noise floor, saturation) are ignored.

    Returns
    -------
    ``(3, 3)`` coefficients ``[channel, (a1, a2, a3)]``.

    Each usable sample gives ``Σ a_m y^m - log E_j = log t`` with ``y = log z``;
    subtracting each point's mean equation eliminates ``log E_j``.
    """
    s = np.asarray(samples, np.float64) / max_code
    J, K, _ = s.shape
    t = np.broadcast_to(np.asarray(times, np.float64), (J, K))
    coef = np.zeros((3, 3))
    for c in range(3):
        z = s[..., c]
        ok = (z > low) & (z < high)
        ok &= ok.sum(axis=1, keepdims=True) >= 2  # a point needs two usable exposures
        if ok.sum() < 8:
            raise ResponseError(f"channel {'RGB'[c]}: only {int(ok.sum())} usable bracket samples; "
                                "need points well exposed in at least two exposures of a bracket")
        # Debevec's hat weight: dark codes are noise-dominated, bright ones near the clip.
        w = np.where(ok, np.minimum(z, 1.0 - z), 0.0)
        y = np.log(np.where(ok, z, 1.0))
        wsum = w.sum(axis=1, keepdims=True)
        wsum = np.where(wsum > 0, wsum, 1.0)
        cols = [(y**m - (w * y**m).sum(axis=1, keepdims=True) / wsum) for m in (1, 2, 3)]
        lt = np.log(t)
        rhs = lt - (w * lt).sum(axis=1, keepdims=True) / wsum
        sw = np.sqrt(w)[ok]
        A = np.stack([col[ok] for col in cols], axis=1) * sw[:, None]
        coef[c], *_ = np.linalg.lstsq(A, rhs[ok] * sw, rcond=None)
    return coef


def cubic_curve(coefficients: np.ndarray, bits: int, low: float = 0.0) -> ResponseCurve:
    """A :class:`ResponseCurve` from per-channel cubic coefficients ``(3, 3)``.

    Below the lowest code the fit saw (``low``, normalised) a cubic extrapolates
    wildly; there the curve continues as the tangent line in log-log space.
    """
    coefficients = np.asarray(coefficients, np.float64).reshape(3, 3)
    z = codes(bits)
    with np.errstate(divide="ignore"):
        y = np.log(z)
    y0 = np.log(low) if low > 0 else -np.inf
    cols = []
    for a1, a2, a3 in coefficients:
        poly = lambda v: a1 * v + a2 * v**2 + a3 * v**3  # noqa: E731, B023 (used only in this iteration)
        with np.errstate(invalid="ignore", over="ignore"):
            logg = poly(y)
            if np.isfinite(y0):
                slope = a1 + 2 * a2 * y0 + 3 * a3 * y0**2
                logg = np.where(y < y0, poly(y0) + slope * (y - y0), logg)
            g = np.exp(logg)
        g[0] = 0.0
        cols.append(np.maximum.accumulate(np.nan_to_num(g, nan=0.0, posinf=0.0)))  # guard a non-monotone fit
    return ResponseCurve(np.stack(cols, axis=1))


def recover_debevec(samples: np.ndarray, times, lambda_smooth: float = 10.0,
                    n_samples: int = 200, reference_code: int = 128) -> ResponseCurve:
    """Debevec-Malik recovery from 8-bit brackets.

    ``samples`` is ``(J, K, 3)`` uint8 (J points, K exposures); ``times`` is
    ``(K,)`` (every point seen at the same times) or ``(J, K)`` (each point's
    own times, e.g. from brackets that differ per pose; entries of a shorter
    bracket padded with code 0 carry no weight).  With one set of times the
    solve is OpenCV's ``cv2.createCalibrateDebevec``; otherwise
    :func:`solve_debevec`.  The curve is defined up to scale; it is scaled so
    that ``g(reference_code) = 1`` (compare it with :func:`relative_error`
    ``fit_scale=True``).
    """
    s = np.asarray(samples)
    if s.dtype != np.uint8:
        raise ResponseError(f"Debevec recovery needs 8-bit images, got {s.dtype}")
    J, K, _ = s.shape
    t = np.asarray(times, np.float64)
    if t.ndim == 2:
        if t.shape != (J, K):
            raise ResponseError(f"exposure times of shape {t.shape} for {J} points × {K} exposures")
        if np.allclose(t, t[:1]):
            t = t[0]
    if not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise ResponseError("exposure times must be positive and finite")
    if t.ndim == 1:
        g = _opencv_debevec(s, t, lambda_smooth, n_samples)
    else:
        pick = np.unique(np.linspace(0, J - 1, min(J, 2 * n_samples)).astype(np.int64))
        g = np.stack([np.exp(solve_debevec(s[pick, :, c], t[pick], lambda_smooth, reference_code)) for c in range(3)],
                     axis=1)
    g = np.maximum.accumulate(np.maximum(g, 0.0), axis=0)
    g /= np.where(g[reference_code] > 0, g[reference_code], 1.0)
    return ResponseCurve(g)


def _opencv_debevec(s: np.ndarray, times: np.ndarray, lambda_smooth: float, n_samples: int) -> np.ndarray:
    import cv2

    J, K, _ = s.shape
    side = int(np.ceil(np.sqrt(J)))
    pad = np.zeros((side * side, K, 3), np.uint8)
    pad[:J] = s
    pad[J:] = s[:1]
    images = [np.ascontiguousarray(pad[:, k].reshape(side, side, 3)) for k in range(K)]
    cal = cv2.createCalibrateDebevec(samples=min(n_samples, side * side), lambda_=lambda_smooth, random=False)
    return cal.process(images, np.asarray(times, np.float32)).reshape(256, 3).astype(np.float64)


def solve_debevec(z: np.ndarray, times: np.ndarray, lambda_smooth: float = 10.0,
                  reference_code: int = 128) -> np.ndarray:
    """Debevec & Malik's least-squares solve for one channel, each sample with its own exposure time.

    ``z`` is ``(P, K)`` 8-bit codes of P scene points, ``times`` their ``(P, K)`` exposure times.  Unknowns: the
    log inverse response ``g(0..255)`` and each point's log radiance ``ln E_p``; equations, weighted by the hat
    ``w(z) = min(z, 255 − z)``: ``g(z_pk) − ln E_p = ln t_pk``, ``λ w(z) g''(z) = 0`` and ``g(reference) = 0``.
    Returns ``g`` (natural log of the relative exposure), ``(256,)``.
    """
    z = np.asarray(z, np.int64)
    P, K = z.shape
    lt = np.log(np.asarray(times, np.float64))
    hat = np.minimum(np.arange(256), 255 - np.arange(256)).astype(np.float64)
    w = hat[z].ravel()
    n_data, n_smooth = P * K, 254
    A = np.zeros((n_data + 1 + n_smooth, 256 + P))
    b = np.zeros(A.shape[0])
    rows = np.arange(n_data)
    A[rows, z.ravel()] = w
    A[rows, 256 + np.repeat(np.arange(P), K)] = -w
    b[:n_data] = w * lt.ravel()
    A[n_data, reference_code] = 1.0
    k = np.arange(1, 255)
    r = n_data + 1 + np.arange(n_smooth)
    A[r, k - 1], A[r, k], A[r, k + 1] = lambda_smooth * hat[k], -2.0 * lambda_smooth * hat[k], lambda_smooth * hat[k]
    seen = np.bincount(z.ravel()[w > 0], minlength=256)
    if np.count_nonzero(seen) < 16:
        raise ResponseError(f"only {np.count_nonzero(seen)} distinct well-exposed codes in the bracket samples; "
                            "need brackets whose exposures spread over the code range")
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    return x[:256]


def bracket_samples(brackets: Sequence[Sequence[np.ndarray]], times: Sequence[Sequence[float]], max_points: int = 4000,
                    seed: int = 0, low: float = 0.02, high: float = 0.98, max_code: int = 255) -> tuple[np.ndarray, np.ndarray]:
    """Pick scene points for response recovery from several brackets of exposures each.

    Returns ``(J, K, 3)`` codes of points that are well exposed (all channels
    inside ``(low, high)``) in at least two exposures, drawn evenly from the
    brackets, and their ``(J, K)`` exposure times.  Brackets may differ in
    their times and in their length: K is the longest, and a shorter
    bracket's missing exposures are code 0 at time 1 s, which every recovery
    ignores (below ``low``, zero hat weight).
    """
    rng = np.random.default_rng(seed)
    per = max(1, max_points // max(len(brackets), 1))
    K = max((len(images) for images in brackets), default=0)
    out, out_times = [], []
    for images, bracket_times in zip(brackets, times):
        stack = np.stack([np.asarray(im).reshape(-1, 3) for im in images], axis=1)  # (N, k, 3)
        z = stack / max_code
        good = ((z > low) & (z < high)).all(axis=2).sum(axis=1) >= 2
        idx = np.flatnonzero(good)
        if idx.size:
            pick = np.sort(rng.choice(idx, size=min(per, idx.size), replace=False))
            codes_ = np.zeros((pick.size, K, 3), stack.dtype)
            codes_[:, :len(images)] = stack[pick]
            t = np.ones((pick.size, K))
            t[:, :len(images)] = np.asarray(bracket_times, np.float64)
            out.append(codes_)
            out_times.append(t)
    if not out:
        raise ResponseError("no pixel is well exposed in two exposures of any bracket; cannot recover a response curve")
    return np.concatenate(out), np.concatenate(out_times)
