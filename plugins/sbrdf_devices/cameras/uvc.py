"""uvc: USB webcams and capture cards (UVC, V4L2) through OpenCV's ``VideoCapture``.

============================  ======  ===========================================================
parameter                     type    meaning (default)
============================  ======  ===========================================================
``source``                    str     device index (``"0"``), device path (``/dev/video0``), or a
                                      video file / image sequence (``frames/%04d.png``) (``"0"``)
``serial``                    str     recorded only: OpenCV cannot read a serial number (none)
``pixel_format``              str     FOURCC asked of the device (``MJPG``, ``YUYV``) (its own)
``gain_db``                   float   must stay 0: UVC gain has no unit (0)
``black_level``               float   UVC has no black level; must stay unset (none)
``trigger``                   str     ``software`` only: a UVC camera free-runs, the driver
                                      drops ``flush_frames`` frames after each exposure change
                                      and the motion, then keeps the next one
``timeout_s``                 float   recorded; V4L2's own read timeout applies (5)
``nominal_exposure_s``        float   a source without exposure control (a file) is taken as
                                      having this exposure (none)
``exposure_range_s``          list    ``[shortest, longest]`` the device accepts, s: OpenCV cannot
                                      ask it ([1e-4, 1.0])
``width``, ``height``         int     capture size asked of the device (its own)
``flush_frames``              int     frames discarded before the one kept (2)
============================  ======  ===========================================================

Auto exposure and auto white balance are switched off; exposure is V4L2's
``exposure_time_absolute`` in units of 100 µs.  UVC frames are 8-bit and
gamma-encoded (``linear`` is false), so the capture leaves the response to
be recovered from the exposure brackets (or given to the reader).  A file
or image sequence stands in for the device in tests; its frames are the
files' own, whatever the exposure, which is why it needs ``nominal_exposure_s``.

Install: ``pip install 'sbrdf[uvc]'`` (OpenCV is already a dependency of sbrdf).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

from sbrdf_core.errors import ParameterError
from sbrdf_lib.camera import CameraError, CameraLost, FrameCameraBase, FrameTimeout

from ..declarations import UVC

if TYPE_CHECKING:
    import cv2

#: V4L2 exposure_time_absolute step, s.
V4L2_EXPOSURE_UNIT_S = 1e-4


class UVCCamera(FrameCameraBase):
    """A UVC camera (or a file standing in for one) through ``cv2.VideoCapture``; see the module docstring."""

    name = "uvc"

    params = UVC

    def __init__(self, *, serial: str | None = None, pixel_format: str | None = None, gain_db: float = 0.0,
                 black_level: float | None = None, trigger: str = "software", timeout_s: float = 5.0,
                 nominal_exposure_s: float | None = None, source: str = "0",
                 exposure_range_s: list = [1e-4, 1.0], width: int | None = None,  # noqa: B006
                 height: int | None = None, flush_frames: int = 2):
        super().__init__(serial=serial, pixel_format=pixel_format, gain_db=gain_db, black_level=black_level,
                         trigger=trigger, timeout_s=timeout_s, nominal_exposure_s=nominal_exposure_s)
        if gain_db:
            raise ParameterError("uvc: gain_db must be 0: UVC gain is in the device's own units, not dB")
        if black_level is not None:
            raise ParameterError("uvc: a UVC camera has no black level setting; leave black_level unset")
        if trigger != "software":
            raise ParameterError("uvc: a UVC camera has no trigger input; use trigger: software")
        import cv2

        self._cv2 = cv2
        self.source, self.flush_frames, self.bit_depth, self.linear = str(source), int(flush_frames), 8, False
        self._range = (float(exposure_range_s[0]), float(exposure_range_s[1]))
        self.is_file = not (self.source.isdigit() or self.source.startswith("/dev/"))
        if self.is_file and nominal_exposure_s is None:
            raise ParameterError(f"uvc: {self.source} is a file, whose frames have no exposure control; give "
                                 "nominal_exposure_s")
        target = int(self.source) if self.source.isdigit() else self.source
        if self.is_file and not (os.path.exists(self.source) or "%" in self.source):
            raise CameraLost(f"no file {self.source}", device=self.name, port=self.source)
        self._cap: cv2.VideoCapture | None = cv2.VideoCapture(target, cv2.CAP_IMAGES if "%" in self.source else cv2.CAP_ANY)
        if not self._cap.isOpened():
            self._cap = None
            raise CameraLost(f"could not open {self.source} (no such device, or it is busy)", device=self.name,
                             port=self.source)
        self.identity = {"vendor": "", "model": f"UVC via OpenCV {self._cap.getBackendName()}", "serial": serial or self.source}
        if not self.is_file:
            props = [(cv2.CAP_PROP_AUTO_EXPOSURE, 1), (cv2.CAP_PROP_AUTO_WB, 0)]
            if pixel_format:
                props.append((cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*pixel_format)))
            props += [(p, v) for p, v in ((cv2.CAP_PROP_FRAME_WIDTH, width), (cv2.CAP_PROP_FRAME_HEIGHT, height))
                      if v is not None]
            for prop, value in props:
                self._cap.set(prop, value)
        self.pixel_format = pixel_format or "BGR8"
        self.width = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))

    def _device_range_s(self) -> tuple[float, float] | None:
        return None if self.is_file else self._range

    def _set_exposure(self, exposure_s: float) -> float:
        units = max(1, round(exposure_s / V4L2_EXPOSURE_UNIT_S))
        assert self._cap is not None, "set_exposure() checks that the camera is open"
        if not self._cap.set(self._cv2.CAP_PROP_EXPOSURE, units):
            raise self.error(CameraError, "the device did not accept the exposure (does it allow manual exposure?)",
                             command=f"exposure_time_absolute = {units}")
        return float(self._cap.get(self._cv2.CAP_PROP_EXPOSURE)) * V4L2_EXPOSURE_UNIT_S

    def _grab(self, timeout_s: float, **_: Any) -> np.ndarray:
        cap = self._cap
        if cap is None or not cap.isOpened():
            raise self.error(CameraLost, "the device is gone")
        for _flushed in range(0 if self.is_file else self.flush_frames):
            cap.grab()
        ok, frame = cap.read()
        if not ok or frame is None:
            if self.is_file:
                raise self.error(CameraLost, f"{self.source} has no more frames", command="read")
            if not cap.isOpened():
                raise self.error(CameraLost, "the device disappeared", command="read")
            raise self.error(FrameTimeout, "no frame", command="read")
        if frame.ndim == 3:
            frame = frame[..., ::-1]  # OpenCV delivers BGR
        self.height, self.width = frame.shape[:2]
        return frame

    def _close(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()
