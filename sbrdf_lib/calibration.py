"""Dark frames and flat fields: what a camera adds to every photograph, measured and taken out again.

Two calibration captures correct a photograph's linear signal ``S`` (codes
through the inverse response, as :mod:`sbrdf_capture.folder` linearises them)
before the exposures of a pose are merged:

    S_corrected = (S - D(t)) / F                                         (1)

* ``D(t) = offset + rate · t`` is the dark signal at exposure ``t``: a
  pedestal (the black level, every frame alike) plus dark current growing
  with the exposure.  Dark frames (lens capped, light off) at two or more
  exposure times separate the two per sensel by least squares
  (:func:`fit_dark`); dark frames at one time only measure their sum, which
  is then used as a pedestal at every exposure (right for the black level,
  and for dark current only at that time).
* ``F`` is the flat field: a uniform target (a diffuser over the lens, an
  integrating sphere's port) photographed, dark-corrected, and normalised to
  1 at the image centre (:func:`normalise_flat`), so the corrected signal of
  an on-axis pixel, to which the light and radiometric calibration refer,
  keeps its value while vignetting and pixel-to-pixel sensitivity are
  divided out everywhere else.

Averaging ``N`` frames per calibration divides their noise by ``√N``; that
noise is then added to every corrected photograph, so take many (the nodes
default to 8).  The arrays are per sensel and channel, ``(H, W, 3)`` float32.

>>> import numpy as np
>>> times = [0.1, 1.0]
>>> frames = [np.full((1, 2, 3), 0.02 + 0.003 * t, np.float32) for t in times]
>>> offset, rate = fit_dark(times, frames)
>>> round(float(offset[0, 0, 0]), 6), round(float(rate[0, 0, 0]), 6)
(0.02, 0.003)
>>> flat = normalise_flat(np.array([[[0.5] * 3, [0.25] * 3]], np.float32), centre_fraction=0.5)
>>> correct(np.full((1, 2, 3), 0.2, np.float32), 1.0, offset, rate, flat)[0, :, 0]  # doctest: +ELLIPSIS
array([0.177..., 0.354...], dtype=float32)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["MIN_FLAT", "correct", "dark_at", "fit_dark", "flat_usable", "linear_signal", "normalise_flat"]

#: Sensels whose normalised flat is below this see too little of the scene to correct (a dead sensel, the
#: black corner of a strongly vignetted lens); their pixels are invalid.
MIN_FLAT = 0.05


def linear_signal(frame: np.ndarray, response=None) -> np.ndarray:
    """A raw frame's linear signal: integer codes through ``response`` (a
    :class:`~sbrdf_lib.response.ResponseCurve`) or normalised by the dtype's maximum when it is ``None``
    (a linear camera); float frames are linear already."""
    a = np.asarray(frame)
    if a.dtype.kind == "f":
        return a.astype(np.float32)
    if response is not None:
        return response.linearize(a)
    return a.astype(np.float32) / np.float32(np.iinfo(a.dtype).max)


def fit_dark(times_s: Sequence[float], frames: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(offset, rate)`` per sensel from mean dark frames (linear signal) at ``times_s``.

    Least squares of ``offset + rate · t`` over the distinct times; with one
    distinct time the rate is 0 and the offset is that frame (module docstring).
    """
    t = np.asarray(times_s, np.float64)
    if len(t) != len(frames) or not len(t):
        raise ValueError(f"fit_dark: {len(frames)} frames for {len(t)} times")
    stack = np.stack([np.asarray(f, np.float64) for f in frames])
    if np.ptp(t) == 0:
        return stack.mean(axis=0).astype(np.float32), np.zeros(stack.shape[1:], np.float32)
    tc = t - t.mean()
    rate = np.tensordot(tc, stack - stack.mean(axis=0), axes=(0, 0)) / float(tc @ tc)
    offset = stack.mean(axis=0) - rate * t.mean()
    return offset.astype(np.float32), rate.astype(np.float32)


def dark_at(offset: np.ndarray, rate: np.ndarray, time_s: float) -> np.ndarray:
    """The dark signal ``D(t) = offset + rate · t`` of an exposure of ``time_s`` seconds."""
    return np.asarray(offset, np.float32) + np.asarray(rate, np.float32) * np.float32(time_s)


def normalise_flat(flat: np.ndarray, centre_fraction: float = 0.1) -> np.ndarray:
    """A dark-corrected flat ``(H, W, 3)`` divided, per channel, by its mean over the central window.

    The window is ``centre_fraction`` of the height and width (at least one
    pixel), centred on the image: a lens vignettes least on its axis, so the
    normalised flat is 1 there and below 1 towards the corners.
    """
    f = np.asarray(flat, np.float64)
    H, W = f.shape[:2]
    h, w = max(1, round(H * centre_fraction)), max(1, round(W * centre_fraction))
    r0, c0 = (H - h) // 2, (W - w) // 2
    ref = f[r0:r0 + h, c0:c0 + w].reshape(-1, f.shape[-1]).mean(axis=0)
    if not (np.isfinite(ref).all() and (ref > 0).all()):
        raise ValueError(f"the flat field's centre has no signal (mean {ref.tolist()} after dark correction): the "
                         "target was not lit, or the dark frame is brighter than the flat")
    return (f / ref).astype(np.float32)


def flat_usable(flat: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: every channel of the normalised flat is at least :data:`MIN_FLAT` (and finite)."""
    f = np.asarray(flat)
    return (np.isfinite(f) & (f >= MIN_FLAT)).all(axis=-1)


def correct(signal: np.ndarray, time_s: float, offset: np.ndarray | None = None, rate: np.ndarray | None = None,
            flat: np.ndarray | None = None) -> np.ndarray:
    """Equation (1): ``(signal - offset - rate · t) / flat``; a missing term is left out.

    Sensels the flat cannot correct (:func:`flat_usable`) keep the
    dark-corrected signal; the caller marks them invalid.  No clamping:
    noise around zero stays unbiased.
    """
    s: np.ndarray = np.asarray(signal, np.float32)
    if offset is not None:
        s = s - np.asarray(offset, np.float32)
    if rate is not None:
        s = s - np.asarray(rate, np.float32) * np.float32(time_s)
    if flat is not None:
        f = np.asarray(flat, np.float32)
        s = s / np.where(flat_usable(f)[..., None], f, np.float32(1.0))
    return s.astype(np.float32, copy=False)
