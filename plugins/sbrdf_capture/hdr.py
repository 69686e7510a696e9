"""Merging exposure brackets into one linear HDR radiance image.

One exposure cannot cover a glossy sample's dynamic range: highlights
saturate where the diffuse part is still near black (seed 000 §3.4.1, 1–3
exposures per pose).  The thesis gives no merge rule; this is the
Debevec-style one: every exposure votes ``g(z)/t`` with a hat weight on its
normalised code ``z``, and codes at or above the saturation level or at or
below the under-exposure level get no vote at all (a clipped value is not a
noisy measurement, it is a bound).  A pixel with no vote in some channel is
*invalid*; it keeps a best guess (the shortest exposure for saturated, the
longest for dark pixels) so images stay viewable, but the validity mask says
not to use it.

Dark current adds a per-sensel signal proportional to exposure time; a dark
frame (lens capped) measured at ``dark_time_s`` is subtracted after scaling
to each exposure's time (:func:`subtract_dark`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def hat_weight(z: np.ndarray, saturation: float, underexposure: float) -> np.ndarray:
    """Triangle weight peaking at mid-range; zero at or beyond the two levels."""
    w = 1.0 - np.abs(2.0 * z - 1.0)
    return np.where((z < saturation) & (z > underexposure), np.maximum(w, 1e-3), 0.0).astype(np.float32)


def subtract_dark(signal: np.ndarray, dark_signal: np.ndarray | None, dark_time_s: float, time_s: float) -> np.ndarray:
    """Remove dark current: ``signal - dark · time_s / dark_time_s`` (no clamping: noise stays unbiased)."""
    if dark_signal is None:
        return signal
    return signal - np.asarray(dark_signal, np.float32) * np.float32(time_s / dark_time_s)


def merge_exposures(signals: Sequence[np.ndarray], levels: Sequence[np.ndarray], times: Sequence[float],
                    saturation: float = 0.98, underexposure: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Weighted HDR merge of one pose's bracket.

    Parameters
    ----------
    signals
        Linear relative exposure per exposure, ``(H, W, 3)`` float32 (after the
        inverse response and dark subtraction).
    levels
        The normalised raw level ``z`` in [0, 1] per exposure, ``(H, W, 3)``:
        ``code / max_code`` for integer images, ``signal / white_level`` for
        linear ones.  Saturation and under-exposure are judged on it.
    times
        Exposure times, s.

    Returns
    -------
    radiance ``(H, W, 3) float32`` (= signal / time) and valid ``(H, W) bool``.
    """
    num = np.zeros(signals[0].shape, np.float32)
    den = np.zeros(signals[0].shape, np.float32)
    shortest = int(np.argmin(times))
    longest = int(np.argmax(times))
    any_saturated = np.zeros(signals[0].shape, bool)
    for s, z, t in zip(signals, levels, times):
        w = hat_weight(z, saturation, underexposure)
        num += w * (s / np.float32(t))
        den += w
        any_saturated |= z >= saturation
    ok = den > 0
    fallback = np.where(any_saturated, signals[shortest] / np.float32(times[shortest]),
                        signals[longest] / np.float32(times[longest]))
    radiance = np.where(ok, num / np.where(ok, den, 1.0), fallback).astype(np.float32)
    return radiance, np.asarray(ok.all(axis=-1))  # (H, W): an array, which the stubs cannot tell from a scalar
