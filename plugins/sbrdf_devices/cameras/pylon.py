"""pylon: Basler cameras (GigE, USB3, CXP) through ``pypylon``.

============================  ======  ===========================================================
parameter                     type    meaning (default)
============================  ======  ===========================================================
``serial``                    str     serial number of the camera (the first one found)
``pixel_format``              str     ``Mono8``, ``Mono12``, ``Mono16``, ``RGB8Packed``,
                                      ``RGB16Packed``, ``Bayer??8/12/16`` (the camera's own)
``gain_db``                   float   analogue gain, dB; ``GainAuto`` is switched off (0)
``black_level``               float   ``BlackLevel`` in camera units (the camera's own)
``trigger``                   str     ``software``: ``TriggerSoftware`` per frame; ``hardware``:
                                      the frame starts on a rising edge of ``Line1`` (software)
``timeout_s``                 float   frame timeout after the exposure, s (5)
``nominal_exposure_s``        float   unused: every Basler camera has exposure control (none)
``width``, ``height``         int     region of interest, px from the top left (the sensor's)
``emulation_frames``          str     emulated cameras only: serve frames from image files, a
                                      pattern with ``{pose}`` and ``{exposure}`` fields (none)
============================  ======  ===========================================================

The driver opens the camera, switches ``ExposureAuto``, ``GainAuto`` and
``BalanceWhiteAuto`` off, sets the pixel format, gain, black level and
``TriggerSelector = FrameStart``, ``TriggerMode = On`` and starts grabbing
one buffer at a time.  Each :meth:`~sbrdf_lib.camera.FrameCameraBase.grab`
waits for the camera to be ready for a trigger, fires it (software trigger),
and retrieves the buffer: an incomplete buffer or none within the timeout
is a :class:`~sbrdf_lib.camera.FrameTimeout`, a removed device a
:class:`~sbrdf_lib.camera.CameraLost`.  Exposure is ``ExposureTime`` (SFNC 2,
µs) or ``ExposureTimeAbs`` (older GigE cameras); Bayer formats are
demosaiced bilinearly (a linear operation, so linear codes stay linear).

**Without a camera**: ``PYLON_CAMEMU=N`` makes the pylon runtime (in the
``pypylon`` wheel) list ``N`` emulated cameras.  With ``emulation_frames``
the emulator's test pattern is off and each frame is the file the pattern
names for the pose and bracket exposure being taken, which is how the tests
feed the virtual rig's photographs through a real driver::

    camera: {device: pylon, params: {pixel_format: RGB16Packed, width: 1024, height: 768,
             emulation_frames: /scans/virtual/images/p{pose:05d}_e{exposure}.png}}

Install: ``pip install 'sbrdf[pylon]'`` (the ``pypylon`` wheel carries the runtime).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from sbrdf_core.extras import require
from sbrdf_lib.camera import CameraError, CameraLost, FrameCameraBase, FrameTimeout

from ..declarations import PYLON

#: Bits per code of the pixel formats the driver reads, and whether the buffer holds RGB triples.
FORMATS = {"Mono8": (8, 1), "Mono10": (10, 1), "Mono12": (12, 1), "Mono16": (16, 1),
           "RGB8Packed": (8, 3), "RGB8": (8, 3), "RGB16Packed": (16, 3), "RGB16": (16, 3)}
for _b in (8, 10, 12, 16):
    for _p in ("GR", "RG", "GB", "BG"):
        FORMATS[f"Bayer{_p}{_b}"] = (_b, 0)  # 0: a mosaic, demosaiced to 3 channels


def _demosaic(raw: np.ndarray, pattern: str) -> np.ndarray:
    import cv2

    # OpenCV names a Bayer pattern by the second row's first two pixels, GenICam by the first row's.
    code = {"RG": cv2.COLOR_BayerBG2RGB, "BG": cv2.COLOR_BayerRG2RGB, "GR": cv2.COLOR_BayerGB2RGB,
            "GB": cv2.COLOR_BayerGR2RGB}[pattern]
    return cv2.cvtColor(raw, code)


class PylonCamera(FrameCameraBase):
    """A Basler camera (or the pylon emulator) through pypylon; see the module docstring."""

    name = "pylon"

    params = PYLON

    def __init__(self, *, serial: str | None = None, pixel_format: str | None = None, gain_db: float = 0.0,
                 black_level: float | None = None, trigger: str = "software", timeout_s: float = 5.0,
                 nominal_exposure_s: float | None = None, width: int | None = None, height: int | None = None,
                 emulation_frames: str | None = None):
        super().__init__(serial=serial, pixel_format=pixel_format, gain_db=gain_db, black_level=black_level,
                         trigger=trigger, timeout_s=timeout_s, nominal_exposure_s=nominal_exposure_s)
        self.emulation_frames = emulation_frames
        self._pylon = require("pypylon.pylon", extra="pylon", feature="the pylon camera driver")
        self._genicam = require("pypylon.genicam", extra="pylon", feature="the pylon camera driver")
        self._cam: Any = None  # a pypylon InstantCamera while open (pypylon ships no type information)
        try:
            self._open(width, height)
        except BaseException:
            self.close()
            raise

    def _open(self, width: int | None, height: int | None) -> None:
        pylon, genicam = self._pylon, self._genicam
        tl = pylon.TlFactory.GetInstance()
        devices = list(tl.EnumerateDevices())
        found = [(d.GetSerialNumber(), d.GetModelName()) for d in devices]
        chosen = [d for d in devices if self.serial is None or d.GetSerialNumber() == self.serial]
        if not chosen:
            raise self.error(CameraLost, f"no Basler camera{f' with serial {self.serial}' if self.serial else ''} "
                             f"found (found {found or 'none'}); check the cable and power, or set PYLON_CAMEMU=1 "
                             "for an emulated camera")
        dev = chosen[0]
        self.identity = {"vendor": dev.GetVendorName(), "model": dev.GetModelName(), "serial": dev.GetSerialNumber()}
        self.emulated = dev.GetDeviceClass() == "BaslerCamEmu"
        if self.emulation_frames and not self.emulated:
            raise self.error(CameraError, "emulation_frames serves image files as frames and is only for an "
                             f"emulated camera (PYLON_CAMEMU); {self.identity['model']} is a real one")
        try:
            self._cam = pylon.InstantCamera(tl.CreateDevice(dev))
            self._cam.Open()
            self._configure(width, height)
            self._cam.StartGrabbing(pylon.GrabStrategy_OneByOne)
        except genicam.GenericException as e:
            raise self.error(CameraError, f"could not be configured: {e}") from e

    def _node(self, name: str):
        """A node of the camera's node map, or ``None`` when the camera lacks it."""
        node = self._cam.GetNodeMap().GetNode(name)
        return node if node is not None and self._genicam.IsAvailable(node) else None

    def _set(self, name: str, value: Any, required: bool = False) -> bool:
        node = self._node(name)
        if node is None or not self._genicam.IsWritable(node):
            if required:
                raise self.error(CameraError, f"has no writable {name}", command=f"{name} = {value}")
            return False
        try:
            node.SetValue(value)
        except self._genicam.GenericException as e:
            raise self.error(CameraError, f"refused {name} = {value!r}: {e}", command=f"{name} = {value}") from e
        return True

    def _configure(self, width: int | None, height: int | None) -> None:
        for auto in ("ExposureAuto", "GainAuto", "BalanceWhiteAuto"):
            self._set(auto, "Off")
        if self.pixel_format is not None:
            if self.pixel_format not in FORMATS:
                raise self.error(CameraError, f"pixel format {self.pixel_format!r} is not read by this driver; "
                                 f"choose one of {sorted(FORMATS)}")
            self._set("PixelFormat", self.pixel_format, required=True)
        self.pixel_format = self._node("PixelFormat").ToString()
        if self.pixel_format not in FORMATS:
            raise self.error(CameraError, f"the camera delivers {self.pixel_format}, which this driver does not read; "
                             f"set pixel_format to one of {sorted(FORMATS)}")
        self.bit_depth, self._channels = FORMATS[self.pixel_format]
        for name, value in (("OffsetX", 0), ("OffsetY", 0)):
            self._set(name, value)
        if width is not None:
            self._set("Width", int(width), required=True)
        if height is not None:
            self._set("Height", int(height), required=True)
        self.width, self.height = int(self._node("Width").GetValue()), int(self._node("Height").GetValue())
        if not self._set("Gain", float(self.gain_db)) and self.gain_db:
            raise self.error(CameraError, "has no Gain feature in dB; leave gain_db at 0", command="Gain")
        if self.black_level is not None:
            self._set("BlackLevel", float(self.black_level)) or self._set("BlackLevelRaw", int(self.black_level),
                                                                          required=True)
        else:
            node = self._node("BlackLevel") or self._node("BlackLevelRaw")
            self.black_level = float(node.GetValue()) if node is not None else None
        self._set("TriggerSelector", "FrameStart")
        self._set("TriggerMode", "On", required=True)
        self._set("TriggerSource", "Software" if self.trigger == "software" else "Line1", required=True)
        if self.emulated:
            self._set("TestImageSelector", "Off")
            self._set("ImageFileMode", "On" if self.emulation_frames else "Off")
        self._exposure_node = self._node("ExposureTime") or self._node("ExposureTimeAbs")

    # -- FrameCameraBase ----------------------------------------------------------------------

    def _alive(self, command: str) -> None:
        """Refuse to touch the node map of a removed device: its nodes dangle (calling one aborts the process)."""
        if self._removed():
            raise self.error(CameraLost, "the camera disappeared (unplugged or powered off)", command=command)

    def _device_range_s(self) -> tuple[float, float] | None:
        self._alive("exposure range")
        n = self._exposure_node
        return None if n is None else (n.GetMin() * 1e-6, n.GetMax() * 1e-6)

    def _set_exposure(self, exposure_s: float) -> float:
        self._alive(f"ExposureTime = {exposure_s * 1e6:g} us")
        try:
            self._exposure_node.SetValue(float(exposure_s) * 1e6)
            return float(self._exposure_node.GetValue()) * 1e-6
        except self._genicam.GenericException as e:
            raise self._failure(e, f"ExposureTime = {exposure_s * 1e6:g} us") from e

    def _grab(self, timeout_s: float, pose_id: int | None = None, exposure_index: int = 0, **_: Any) -> np.ndarray:
        pylon, genicam = self._pylon, self._genicam
        cam = self._cam
        ms = max(1, int(round(timeout_s * 1000)))
        self._alive("trigger and retrieve")
        try:
            if self.emulation_frames:
                path = self.emulation_frames.format(pose=pose_id if pose_id is not None else 0, exposure=exposure_index)
                if not os.path.isfile(path):
                    raise self.error(CameraError, f"emulation_frames: no image {path} for pose {pose_id} exposure "
                                     f"{exposure_index}")
                # The emulator locks ImageFilename while grabbing; switching files costs a stop and a start.
                cam.StopGrabbing()
                self._set("ImageFilename", path, required=True)
                cam.StartGrabbing(pylon.GrabStrategy_OneByOne)
            if self.trigger == "software":
                cam.WaitForFrameTriggerReady(ms, pylon.TimeoutHandling_ThrowException)
                cam.ExecuteSoftwareTrigger()
            result = cam.RetrieveResult(ms, pylon.TimeoutHandling_Return)
        except genicam.GenericException as e:
            raise self._failure(e, "trigger and retrieve") from e
        if result is None or not result.IsValid():
            if self._removed():
                raise self.error(CameraLost, "the camera was removed while waiting for a frame", command="retrieve")
            raise self.error(FrameTimeout, f"no frame within {timeout_s:g} s of the trigger", command="retrieve")
        try:
            if not result.GrabSucceeded():
                raise self.error(FrameTimeout, f"the frame arrived incomplete ({result.GetErrorDescription()})",
                                 command="retrieve")
            h, w = int(result.GetHeight()), int(result.GetWidth())
            dtype = np.uint8 if self.bit_depth == 8 else np.uint16
            data = np.frombuffer(bytes(result.GetBuffer()), dtype)
            row = w * max(self._channels, 1) + int(result.GetPaddingX()) // np.dtype(dtype).itemsize
            frame = data[: h * row].reshape(h, row)[:, : w * max(self._channels, 1)]
            frame = frame.reshape(h, w, self._channels) if self._channels == 3 else frame.reshape(h, w)
            if self._channels == 0:
                assert self.pixel_format is not None, "_configure() reads the camera's pixel format"
                frame = _demosaic(np.ascontiguousarray(frame), self.pixel_format[5:7])
            return frame.copy()
        finally:
            result.Release()

    def _removed(self) -> bool:
        cam = self._cam
        try:
            return cam is None or not cam.IsPylonDeviceAttached() or cam.IsCameraDeviceRemoved()
        except Exception:  # noqa: BLE001 - a camera that cannot even answer this is gone
            return True

    def _failure(self, e: Exception, command: str) -> CameraError:
        if self._removed():
            return self.error(CameraLost, f"the camera disappeared (unplugged or powered off): {e}", command=command)
        if isinstance(e, self._genicam.TimeoutException):
            return self.error(FrameTimeout, f"timed out: {e}", command=command)
        return self.error(CameraError, str(e), command=command)

    def _close(self) -> None:
        cam, self._cam = self._cam, None
        if cam is not None:
            try:
                if cam.IsGrabbing():
                    cam.StopGrabbing()
            finally:
                cam.Close()
                cam.DestroyDevice()
