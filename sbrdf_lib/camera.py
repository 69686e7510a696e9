"""What every frame-camera driver shares: errors, the declared settings, frame normalisation.

A *frame camera* (:class:`sbrdf_core.contracts.FrameCamera`) is a physical
camera, or a vendor's emulation of one, that a capture source configures once
and then triggers frame by frame: the ``pylon``, ``aravis``, ``genicam``, ``uvc`` and
``gphoto`` devices.  Unlike the virtual camera it knows nothing of the
sample, the light or its own pose; it delivers raw codes at an exposure
time, and the ``gonio`` source records the geometry.

The invariants every driver keeps, so capture code never asks which camera it
has:

* :meth:`FrameCameraBase.grab` returns ``(H, W, 3)`` ``uint8`` or ``uint16``
  codes, *MSB-aligned*: full scale is the dtype's maximum whatever the
  sensor's bit depth (a 12-bit code ``c`` is delivered as ``c << 4``), so the
  capture folder's "linear integer codes are normalised by the dtype's
  maximum" holds and a clipped pixel reads at or near 1.  A monochrome sensor's
  code is repeated in the three channels.
* Settings that would make the codes non-linear or frame-dependent are off
  where the camera has them: automatic exposure, automatic gain, automatic
  white balance.  What the camera was set to (gain, black level, pixel
  format, trigger) and who it is (vendor, model, serial number) is returned
  by ``info()`` and recorded in the capture's ``camera.device`` section.
* Every failure is a :class:`CameraError` (a
  :class:`~sbrdf_lib.serial.errors.DeviceError`, so the ``gonio`` source
  handles cameras and motors alike) naming the device, its serial number and
  what it was doing; :class:`CameraLost`, :class:`FrameTimeout` and
  :class:`ExposureRefused` say which of the documented faults happened.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from sbrdf_lib.serial.errors import DeviceError

from .camera_params import COMMON_PARAMS

__all__ = ["COMMON_PARAMS", "CameraError", "CameraLost", "ExposureRefused", "FrameCameraBase", "FrameTimeout",
           "msb_align", "saturated_fraction", "to_rgb"]

log = logging.getLogger(__name__)


class CameraError(DeviceError):
    """A camera failed; ``device`` is the driver's registry name and ``port`` the camera's serial number."""


class CameraLost(CameraError):
    """The camera went away (unplugged, powered off, its transport layer closed); never retried."""


class FrameTimeout(CameraError):
    """No frame arrived within the frame timeout after the trigger (the ``gonio`` source retries it)."""


class ExposureRefused(CameraError):
    """The camera cannot take this exposure time (outside its range, or it has no exposure control)."""


def to_rgb(frame: np.ndarray) -> np.ndarray:
    """``(H, W)`` or ``(H, W, 1|3|4)`` -> ``(H, W, 3)``; a mono code goes to every channel, alpha is dropped."""
    a = np.asarray(frame)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
        raise ValueError(f"expected a (H, W[, 1|3|4]) frame, got shape {a.shape}")
    if a.shape[2] == 1:
        return np.repeat(a, 3, axis=2)
    return np.ascontiguousarray(a[..., :3])


def msb_align(frame: np.ndarray, bit_depth: int) -> np.ndarray:
    """Codes of ``bit_depth`` bits in a uint8/uint16 container, shifted so full scale is the dtype's maximum."""
    a = np.asarray(frame)
    container = 8 * a.dtype.itemsize
    if a.dtype.kind != "u" or container not in (8, 16):
        raise ValueError(f"expected uint8/uint16 codes, got {a.dtype}")
    shift = container - int(bit_depth)
    if shift < 0:
        raise ValueError(f"a {bit_depth}-bit code does not fit {a.dtype}")
    return a if shift == 0 else np.left_shift(a, shift, dtype=a.dtype)


def saturated_fraction(frame: np.ndarray, level: float = 0.98) -> float:
    """Share of pixels with a channel at or above ``level`` of full scale (the folder reader's saturation)."""
    a = np.asarray(frame)
    full = float(np.iinfo(a.dtype).max) if a.dtype.kind == "u" else 1.0
    return float(np.mean((a >= level * full).any(axis=-1))) if a.size else 0.0


class FrameCameraBase:
    """The shared half of a frame-camera driver: settings, exposure checks, timing, frame shape.

    A driver subclasses it, sets ``name`` (its registry name), declares
    ``params = COMMON_PARAMS + (...)``, and implements ``_open()``,
    ``_device_range_s()``, ``_set_exposure(seconds) -> seconds``, ``_grab(timeout_s, **kw) -> raw`` (any
    ``(H, W[, C])`` array; :meth:`grab` makes it ``(H, W, 3)`` MSB-aligned) and ``_close()``.
    """

    name = "frame-camera"

    def __init__(self, *, serial: str | None = None, pixel_format: str | None = None, gain_db: float = 0.0,
                 black_level: float | None = None, trigger: str = "software", timeout_s: float = 5.0,
                 nominal_exposure_s: float | None = None):
        self.serial, self.pixel_format, self.gain_db, self.black_level = serial, pixel_format, float(gain_db), black_level
        self.trigger, self.timeout_s, self.nominal_exposure_s = trigger, float(timeout_s), nominal_exposure_s
        self.exposure_s: float | None = None
        self.width = self.height = 0  # set by the driver once the camera is open
        self.bit_depth = 8
        self.linear = True
        self.identity = {"vendor": "", "model": "", "serial": serial or ""}
        #: Seconds spent in the last :meth:`grab`: integrating (the exposure) and the rest (trigger, readout, transfer).
        self.last_timing = {"exposure": 0.0, "transfer": 0.0}
        self._closed = False

    # -- what drivers implement ----------------------------------------------------------------

    def _device_range_s(self) -> tuple[float, float] | None:
        """The exposure range the device accepts, or ``None`` when it has no exposure control."""
        raise NotImplementedError

    def _set_exposure(self, exposure_s: float) -> float:
        raise NotImplementedError

    def _grab(self, timeout_s: float, **kw: Any) -> np.ndarray:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    # -- the contract --------------------------------------------------------------------------

    def error(self, cls: type[CameraError], message: str, command: str | None = None) -> CameraError:
        """A ``cls`` naming this driver and the camera's serial number."""
        return cls(message, device=self.name, port=self.identity.get("serial") or self.serial or "?", command=command)

    def info(self) -> dict:
        """Who the camera is and how it is set: the capture's ``camera.device`` record."""
        return {"driver": self.name, **self.identity, "width": self.width, "height": self.height,
                "pixel_format": self.pixel_format, "bit_depth": self.bit_depth,
                "linear": self.linear, "gain_db": self.gain_db, "black_level": self.black_level,
                "white_balance": "off", "trigger": self.trigger, "timeout_s": self.timeout_s}

    def exposure_range_s(self) -> tuple[float, float]:
        """``(shortest, longest)`` exposure time the camera accepts, s."""
        rng = self._device_range_s()
        if rng is None:
            if self.nominal_exposure_s is None:
                raise self.error(ExposureRefused, "the camera has no exposure control; give nominal_exposure_s (its "
                                 "fixed exposure) to capture with it")
            return (float(self.nominal_exposure_s),) * 2
        return float(rng[0]), float(rng[1])

    def set_exposure(self, exposure_s: float) -> float:
        """Set the exposure time; return the time the camera actually uses (it rounds to its own steps)."""
        self._check_open()
        lo, hi = self.exposure_range_s()
        t = float(exposure_s)
        if not (np.isfinite(t) and lo * (1 - 1e-9) <= t <= hi * (1 + 1e-9)):
            raise self.error(ExposureRefused, f"exposure {t:g} s is outside the camera's range [{lo:g}, {hi:g}] s",
                             command=f"exposure {t:g} s")
        if self._device_range_s() is None:
            assert self.nominal_exposure_s is not None, "exposure_range_s() refuses a camera with neither"
            self.exposure_s = float(self.nominal_exposure_s)
        else:
            self.exposure_s = float(self._set_exposure(t))
        return self.exposure_s

    def grab(self, *, timeout_s: float | None = None, **kw: Any) -> np.ndarray:
        """Trigger (software) or await (hardware) one frame: ``(H, W, 3)`` uint8/uint16, MSB-aligned.

        ``timeout_s`` (default the ``timeout_s`` setting) counts after the
        exposure.  Keywords ``pose_id`` and ``exposure_index`` name the frame
        (drivers may use them to name files or emulated frames; others ignore them).
        """
        self._check_open()
        # Before any set_exposure the camera keeps whatever exposure it has (its timing then counts as transfer).
        wait = (self.timeout_s if timeout_s is None else float(timeout_s)) + float(self.exposure_s or 0.0)
        t0 = time.perf_counter()
        raw = self._grab(wait, **kw)
        wall = time.perf_counter() - t0
        frame = to_rgb(msb_align(raw, self.bit_depth))
        exposure = min(wall, float(self.exposure_s or 0.0))
        self.last_timing = {"exposure": exposure, "transfer": wall - exposure}
        return frame

    def close(self) -> None:
        """Stop acquisition and release the camera; idempotent, safe after a failure."""
        if not self._closed:
            self._closed = True
            try:
                self._close()
            except Exception:  # noqa: BLE001 - closing a lost camera must not mask the error that lost it
                log.debug("%s: closing failed", self.name, exc_info=True)

    def _check_open(self) -> None:
        if self._closed:
            raise self.error(CameraLost, "the camera was closed")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
