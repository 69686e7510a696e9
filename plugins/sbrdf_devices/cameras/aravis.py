"""aravis: GigE Vision and USB3 Vision cameras through the Aravis library (GObject introspection).

============================  ======  ===========================================================
parameter                     type    meaning (default)
============================  ======  ===========================================================
``serial``                    str     serial number of the camera (the first one found)
``pixel_format``              str     ``Mono8``, ``Mono12``, ``Mono16``, ``RGB8``,
                                      ``Bayer??8/12/16`` (the camera's own)
``gain_db``                   float   gain in the camera's ``Gain`` units, dB on SFNC cameras;
                                      ``GainAuto`` is switched off (0)
``black_level``               float   ``BlackLevel`` in camera units (the camera's own)
``trigger``                   str     ``software``: ``TriggerSoftware`` per frame; ``hardware``:
                                      the frame starts on ``Line1`` (software)
``timeout_s``                 float   frame timeout after the exposure, s (5)
``nominal_exposure_s``        float   unused: GenICam cameras have exposure control (none)
``width``, ``height``         int     region of interest, px from the top left (the sensor's)
``buffers``                   int     stream buffers queued for the camera (4)
============================  ======  ===========================================================

Aravis talks GigE Vision and USB3 Vision itself (no vendor SDK, no GenTL
producer) and reads each camera's GenICam description, so one driver serves
any compliant camera.  The driver switches ``ExposureAuto``, ``GainAuto`` and
``BalanceWhiteAuto`` off where the camera has them, sets the pixel format,
region, gain and black level, puts the camera in ``FrameStart`` trigger mode
and continuous acquisition with ``buffers`` queued buffers.  Each
:meth:`~sbrdf_lib.camera.FrameCameraBase.grab` fires ``TriggerSoftware`` and
pops one buffer: none within the timeout, or one whose status is not
success (lost packets), is a :class:`~sbrdf_lib.camera.FrameTimeout`; a camera
that stops answering its control channel (``control-lost``, or a register
access that fails) is a :class:`~sbrdf_lib.camera.CameraLost`.  Exposure is
``ExposureTime`` / ``ExposureTimeAbs`` in µs (Aravis picks the feature).

**Without a camera**: Debian's ``aravis-tools`` has a GigE Vision camera
simulator, ``arv-fake-gv-camera-0.8 -i 127.0.0.1 -s <serial>``, which answers
on the loopback interface (a 512×512 test pattern whose brightness grows
with the exposure time and gain).  The tests run the driver against it.

Install: ``apt install gir1.2-aravis-0.8 libgirepository1.0-dev libcairo2-dev``
then ``pip install 'sbrdf[aravis]'`` (PyGObject; on Debian's own Python,
``apt install python3-gi`` does instead).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sbrdf_core.extras import require
from sbrdf_lib.camera import CameraError, CameraLost, FrameCameraBase, FrameTimeout

from ..declarations import ARAVIS

#: Bits per code of the pixel formats the driver reads, and channels in the buffer (0: a Bayer mosaic).
FORMATS = {"Mono8": (8, 1), "Mono10": (10, 1), "Mono12": (12, 1), "Mono16": (16, 1), "RGB8": (8, 3),
           "RGB8Packed": (8, 3), "RGB16": (16, 3)}
for _b in (8, 10, 12, 16):
    for _p in ("GR", "RG", "GB", "BG"):
        FORMATS[f"Bayer{_p}{_b}"] = (_b, 0)


def _aravis():
    """The ``Aravis`` 0.8 namespace through GObject introspection, with an install hint when missing."""
    gi = require("gi", extra="aravis", feature="the aravis camera driver")
    try:
        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis, GLib
    except (ValueError, ImportError) as e:
        raise CameraError(f"the Aravis 0.8 introspection data is missing ({e}); apt install gir1.2-aravis-0.8",
                          device="aravis", port="?") from None
    return Aravis, GLib


class AravisCamera(FrameCameraBase):
    """A GenICam camera (or Aravis's fake GigE Vision camera) through Aravis; see the module docstring."""

    name = "aravis"

    params = ARAVIS

    def __init__(self, *, serial: str | None = None, pixel_format: str | None = None, gain_db: float = 0.0,
                 black_level: float | None = None, trigger: str = "software", timeout_s: float = 5.0,
                 nominal_exposure_s: float | None = None, width: int | None = None, height: int | None = None,
                 buffers: int = 4):
        super().__init__(serial=serial, pixel_format=pixel_format, gain_db=gain_db, black_level=black_level,
                         trigger=trigger, timeout_s=timeout_s, nominal_exposure_s=nominal_exposure_s)
        self._Aravis, self._GLib = _aravis()
        self._cam: Any = None  # Aravis.Camera once open
        self._stream: Any = None
        self._lost = False
        try:
            self._open(width, height, int(buffers))
        except BaseException:
            self.close()
            raise

    def _open(self, width: int | None, height: int | None, buffers: int) -> None:
        Aravis, GLib = self._Aravis, self._GLib
        Aravis.update_device_list()
        found = [(Aravis.get_device_id(i), Aravis.get_device_serial_nbr(i)) for i in range(Aravis.get_n_devices())]
        chosen = [d for d in found if self.serial is None or d[1] == self.serial]
        if not chosen:
            raise self.error(CameraLost, f"no GenICam camera{f' with serial {self.serial}' if self.serial else ''} found "
                             f"(found {[s for _, s in found] or 'none'}); check the cable, the network interface's "
                             "address and firewall (GigE Vision: UDP 3956), or start arv-fake-gv-camera-0.8 for a "
                             "simulated one")
        try:
            self._cam = Aravis.Camera.new(chosen[0][0])
            cam = self._cam
            self.identity = {"vendor": cam.get_vendor_name(), "model": cam.get_model_name(),
                             "serial": cam.get_device_serial_number()}
            cam.get_device().connect("control-lost", self._on_control_lost)
            self._configure(width, height)
            cam.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
            self._stream = cam.create_stream(None, None)
            size = cam.get_payload()
            for _ in range(buffers):
                self._stream.push_buffer(Aravis.Buffer.new_allocate(size))
            cam.start_acquisition()
        except GLib.Error as e:
            raise self.error(CameraError, f"could not be configured: {e.message}") from None

    def _on_control_lost(self, *_: Any) -> None:
        self._lost = True  # Aravis's heartbeat thread: only a flag, read by the next call

    def _feature(self, name: str) -> bool:
        dev = self._cam.get_device()
        return bool(dev.is_feature_available(name))

    def _configure(self, width: int | None, height: int | None) -> None:
        cam, dev = self._cam, self._cam.get_device()
        for auto in ("ExposureAuto", "GainAuto", "BalanceWhiteAuto"):
            if self._feature(auto):
                dev.set_string_feature_value(auto, "Off")
        if self.pixel_format is not None:
            if self.pixel_format not in FORMATS:
                raise self.error(CameraError, f"pixel format {self.pixel_format!r} is not read by this driver; "
                                 f"choose one of {sorted(FORMATS)}")
            available = list(cam.dup_available_pixel_formats_as_strings())
            if self.pixel_format not in available:
                raise self.error(CameraError, f"has no pixel format {self.pixel_format!r}; it offers {available}",
                                 command=f"PixelFormat = {self.pixel_format}")
            cam.set_pixel_format_from_string(self.pixel_format)
        self.pixel_format = cam.get_pixel_format_as_string()
        if self.pixel_format not in FORMATS:
            raise self.error(CameraError, f"the camera delivers {self.pixel_format}, which this driver does not read; "
                             f"set pixel_format to one of {sorted(FORMATS)}")
        self.bit_depth, self._channels = FORMATS[self.pixel_format]
        region = cam.get_region()
        w = int(width) if width is not None else int(region.width)
        h = int(height) if height is not None else int(region.height)
        cam.set_region(0, 0, w, h)
        region = cam.get_region()
        if (width is not None and region.width != w) or (height is not None and region.height != h):
            raise self.error(CameraError, f"refused the region {w}x{h} (set {region.width}x{region.height})",
                             command="Width, Height")
        self.width, self.height = int(region.width), int(region.height)
        if cam.is_gain_available():
            cam.set_gain(float(self.gain_db))
        elif self.gain_db:
            raise self.error(CameraError, "has no Gain feature; leave gain_db at 0", command="Gain")
        if self.black_level is not None:
            if not self._feature("BlackLevel"):
                raise self.error(CameraError, "has no BlackLevel feature; leave black_level unset", command="BlackLevel")
            cam.set_black_level(float(self.black_level))
        elif self._feature("BlackLevel"):
            self.black_level = float(cam.get_black_level())
        if self._feature("TriggerSelector"):
            dev.set_string_feature_value("TriggerSelector", "FrameStart")
        cam.set_trigger("Software" if self.trigger == "software" else "Line1")

    # -- FrameCameraBase ----------------------------------------------------------------------

    def _alive(self, command: str) -> None:
        if self._lost or self._cam is None:
            raise self.error(CameraLost, "the camera stopped answering (unplugged, powered off or its link is down)",
                             command=command)

    def _device_range_s(self) -> tuple[float, float] | None:
        self._alive("exposure range")
        try:
            if not self._cam.is_exposure_time_available():
                return None
            lo, hi = self._cam.get_exposure_time_bounds()
        except self._GLib.Error as e:
            raise self._failure(e, "exposure range") from None
        return lo * 1e-6, hi * 1e-6

    def _set_exposure(self, exposure_s: float) -> float:
        command = f"ExposureTime = {exposure_s * 1e6:g} us"
        self._alive(command)
        try:
            self._cam.set_exposure_time(float(exposure_s) * 1e6)
            return float(self._cam.get_exposure_time()) * 1e-6
        except self._GLib.Error as e:
            raise self._failure(e, command) from None

    def _grab(self, timeout_s: float, **_: Any) -> np.ndarray:
        Aravis = self._Aravis
        self._alive("trigger and retrieve")
        try:
            if self.trigger == "software":
                self._cam.software_trigger()
        except self._GLib.Error as e:
            raise self._failure(e, "TriggerSoftware") from None
        buf = self._stream.timeout_pop_buffer(max(1, int(timeout_s * 1e6)))
        if buf is None:
            self._alive("retrieve")
            raise self.error(FrameTimeout, f"no frame within {timeout_s:g} s of the trigger", command="retrieve")
        try:
            status = buf.get_status()
            if status != Aravis.BufferStatus.SUCCESS:
                raise self.error(FrameTimeout, f"the frame arrived incomplete ({status.value_nick})", command="retrieve")
            h, w = int(buf.get_image_height()), int(buf.get_image_width())
            dtype = np.uint8 if self.bit_depth == 8 else np.uint16
            c = max(self._channels, 1)
            data = np.frombuffer(bytes(buf.get_data()), dtype)[: h * w * c]
            frame = data.reshape(h, w, c) if c == 3 else data.reshape(h, w)
            if self._channels == 0:
                from .pylon import _demosaic

                frame = _demosaic(np.ascontiguousarray(frame), str(self.pixel_format)[5:7])
            return frame.copy()
        finally:
            self._stream.push_buffer(buf)

    def _failure(self, e: Exception, command: str) -> CameraError:
        message = getattr(e, "message", str(e))
        if self._lost or "timeout" in message.lower():
            self._lost = True
            return self.error(CameraLost, f"the camera stopped answering: {message}", command=command)
        return self.error(CameraError, message, command=command)

    def _close(self) -> None:
        cam, self._cam, self._stream = self._cam, None, None
        if cam is not None and not self._lost:
            cam.stop_acquisition()
