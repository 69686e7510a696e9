"""Power-function compression of a shading map (seed 002 §5, Eq 4).

Per texel and colour channel the N samples s_i of the shading map are
approximated by

    f(x) = k_s · x^K,   x = r / a_max = i / (N − 1),   k_s = s_{N−1}          (Eq 4)

so the fit passes through the brightest slice and 0 at slice 0.  K is found
by brute force as in the paper: a coarse pass over ``[K_min, K_max]`` with a
large step, then a fine pass within one coarse step of the coarse minimum.
For fixed k_s the squared error of every candidate is

    Σ_i s_i² − 2 k_s Σ_i s_i x_i^K + k_s² Σ_i x_i^{2K}

so the coarse pass is one matrix product of the ``(texels·channels, N)``
samples with the ``(N, candidates)`` table of x_i^K; the fine pass, whose
candidates differ per texel, evaluates the same sums on ``(texels, F, N)``
blocks.  Nothing loops over texels in Python.  On data that is a power law
the error in K is at most half the fine step (the squared error is unimodal
in K, so the coarse minimum lies within one coarse step of the truth).
"""

from __future__ import annotations

import numpy as np

#: Defaults of the search: range of K, coarse and fine steps.
EXPONENT_RANGE = (0.05, 12.0)
COARSE_STEP = 0.25
FINE_STEP = 0.01


def _powers(x: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``x^K`` with ``0^K = 0`` (K > 0), broadcasting."""
    with np.errstate(divide="ignore"):
        logx = np.log(x)
    return np.where(x > 0, np.exp(K * np.where(x > 0, logx, 0.0)), 0.0)


def fit_power(samples: np.ndarray, exponent_range=EXPONENT_RANGE, coarse_step: float = COARSE_STEP,
              fine_step: float = FINE_STEP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit Eq 4 to ``samples`` ``(N, ...)`` (slices first): ``(k_s (...), exponent (...), sq_error (...))``.

    ``sq_error`` is the sum over the N slices of the squared residual.  Non-finite samples
    count as 0.  Texels with ``k_s = 0`` get K = 1.

    >>> x = np.linspace(0, 1, 8)[:, None]
    >>> k, K, e = fit_power(0.5 * x ** 2.0)
    >>> float(k[0]), round(float(K[0]), 6), float(e[0]) < 1e-20
    (0.5, 2.0, True)
    """
    lo, hi = float(exponent_range[0]), float(exponent_range[1])
    if not 0 < lo < hi:
        raise ValueError(f"exponent_range must satisfy 0 < low < high, got {exponent_range}")
    if not 0 < fine_step <= coarse_step:
        raise ValueError(f"need 0 < fine_step <= coarse_step, got fine {fine_step}, coarse {coarse_step}")
    s = np.nan_to_num(np.asarray(samples, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    N = s.shape[0]
    if N < 2:
        raise ValueError(f"a shading map needs at least 2 slices, got {N}")
    shape = s.shape[1:]
    S = s.reshape(N, -1).T                                   # (M, N)
    x = np.arange(N) / (N - 1)
    k = S[:, -1]
    ss = (S * S).sum(axis=1)

    # Coarse: every candidate for every texel-channel at once (one matrix product).
    coarse = np.arange(lo, hi + 0.5 * coarse_step, coarse_step)
    X = _powers(x[None, :], coarse[:, None])                 # (J, N)
    err = ss[:, None] - 2 * k[:, None] * (S @ X.T) + (k * k)[:, None] * (X * X).sum(axis=1)[None, :]
    best = coarse[np.argmin(err, axis=1)]

    # Fine: one coarse step either side of the coarse minimum, per texel-channel.
    m = int(round(coarse_step / fine_step))
    offsets = np.arange(-m, m + 1) * fine_step
    K_fine = np.clip(best[:, None] + offsets[None, :], lo, hi)   # (M, F)
    K_out = np.empty(len(S))
    e_out = np.empty(len(S))
    block = max(1, 2_000_000 // (len(offsets) * N))
    for b0 in range(0, len(S), block):                       # blocks bound memory, not a per-texel loop
        b1 = min(b0 + block, len(S))
        P = _powers(x[None, None, :], K_fine[b0:b1, :, None])       # (B, F, N)
        r = S[b0:b1, None, :] - k[b0:b1, None, None] * P
        e = (r * r).sum(axis=-1)
        j = np.argmin(e, axis=1)
        K_out[b0:b1] = K_fine[b0:b1][np.arange(b1 - b0), j]
        e_out[b0:b1] = e[np.arange(b1 - b0), j]
    K_out = np.where(k > 0, K_out, 1.0)
    e_out = np.where(k > 0, e_out, ss)
    return k.reshape(shape), K_out.reshape(shape), e_out.reshape(shape)


def evaluate_power(k_s: np.ndarray, exponent: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Eq 4 at normalised radiance ``x = r / a_max`` (``x >= 0``, broadcasting)."""
    return k_s * _powers(np.asarray(x, np.float64), exponent)


def compress_tile(slices: np.ndarray, exponent_range=EXPONENT_RANGE, coarse_step: float = COARSE_STEP,
                  fine_step: float = FINE_STEP) -> np.ndarray:
    """Kernel for one ``(N, v, u, C)`` tile: ``(v, u, 2C + 1)`` = k_s | K | per-texel RMS (over slices, channels)."""
    N, v, u, C = slices.shape
    k, K, e = fit_power(slices, exponent_range, coarse_step, fine_step)
    rms = np.sqrt(e.sum(axis=-1) / (N * C))
    return np.concatenate([k, K, rms[..., None]], axis=-1).astype(np.float32)
