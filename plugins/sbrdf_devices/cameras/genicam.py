"""genicam: any GenICam camera through its vendor's GenTL producer (a ``.cti`` file), with ``harvesters``.

============================  ======  ===========================================================
parameter                     type    meaning (default)
============================  ======  ===========================================================
``serial``                    str     serial number of the camera, as the producer lists it
                                      (the first one found)
``pixel_format``              str     ``Mono8``, ``Mono12``, ``Mono16``, ``RGB8``, ``RGBa8``,
                                      ``BGR8``, ``Bayer??8/12/16``, ... (the camera's own)
``gain_db``                   float   SFNC ``Gain`` (dB); ``GainAuto`` is switched off (0)
``black_level``               float   ``BlackLevel`` in camera units (the camera's own)
``trigger``                   str     ``software``: ``TriggerSoftware`` per frame; ``hardware``:
                                      the frame starts on ``Line1`` (software)
``timeout_s``                 float   frame timeout after the exposure, s (5)
``nominal_exposure_s``        float   a camera without ``ExposureTime``: the exposure it has, the
                                      only time then accepted (none)
``producer``                  str     the GenTL producer, a ``.cti`` file (every ``.cti`` in the
                                      folders of ``GENICAM_GENTL64_PATH``)
``width``, ``height``         int     region of interest, px from the top left (the sensor's)
``buffers``                   int     buffers the producer fills for the driver (4)
============================  ======  ===========================================================

A GenTL producer is the camera vendor's transport layer as a shared library
(``.cti``): GigE Vision, USB3 Vision, CoaXPress or Camera Link frame
grabbers, or a vendor's own interface.  ``harvesters`` loads it, lists its
cameras, and reads each camera's GenICam description, so the driver speaks
the Standard Features Naming Convention (SFNC) and nothing vendor-specific.
It switches ``ExposureAuto``, ``GainAuto`` and ``BalanceWhiteAuto`` off
where the camera has them, sets the pixel format, region, ``Gain``,
``BlackLevel`` and ``TriggerSelector = FrameStart``, ``TriggerMode = On``,
``TriggerSource = Software`` (or ``Line1``), and starts acquisition.  Each
:meth:`~sbrdf_lib.camera.FrameCameraBase.grab` executes ``TriggerSoftware``
and fetches one complete buffer: none within the timeout is a
:class:`~sbrdf_lib.camera.FrameTimeout`, a transport failure (I/O error, a
closed or invalid handle) a :class:`~sbrdf_lib.camera.CameraLost`.  Exposure
is ``ExposureTime`` (SFNC, µs) or ``ExposureTimeAbs`` (older GigE cameras).

A camera that lacks a feature a setting needs is refused with the feature
named: ``gain_db`` without ``Gain``, ``black_level`` without ``BlackLevel``,
``trigger: hardware`` without ``TriggerMode``.  Without ``ExposureTime`` the
camera cannot bracket exposures: :meth:`exposure_range_s` raises
:class:`~sbrdf_lib.camera.ExposureRefused` naming the model and the feature,
which the ``gonio`` source turns into a refusal before any motor moves,
unless ``nominal_exposure_s`` states the camera's fixed exposure.  A
free-running camera (no ``TriggerMode`` or no ``TriggerSoftware``) is
"software triggered" by starting acquisition for each frame and keeping the
first frame it delivers, which began integrating after the request.

**Without a camera**: the ``genicam`` wheel ships a virtual producer,
``viky.cti`` (next to the ``genicam`` package), with three virtual cameras
(serials ``0``, ``1``, ``2``; 400×400 ``RGBa8`` or ``Mono8``, 100 to 800 px
a side).  They have no ``ExposureTime``, ``Gain``, ``BlackLevel`` or trigger
features, so they check discovery, configuration, frames, identity and the
refusals above, not exposure control.  The tests run the driver against it.

Install: ``pip install 'sbrdf[genicam]'`` (``harvesters`` and ``genicam``),
plus the camera vendor's GenTL producer.
"""

from __future__ import annotations

import glob
import os
import threading
from typing import Any

import numpy as np

from sbrdf_core.extras import require
from sbrdf_lib.camera import CameraError, CameraLost, ExposureRefused, FrameCameraBase, FrameTimeout

from ..declarations import GENICAM

#: Bits per code of the pixel formats the driver reads, channels in the buffer (0: a Bayer mosaic), and whether
#: the channels arrive blue first.
FORMATS = {"Mono8": (8, 1, False), "Mono10": (10, 1, False), "Mono12": (12, 1, False), "Mono14": (14, 1, False),
           "Mono16": (16, 1, False), "RGB8": (8, 3, False), "RGB8Packed": (8, 3, False), "RGBa8": (8, 4, False),
           "RGB10": (10, 3, False), "RGB12": (12, 3, False), "RGB16": (16, 3, False), "BGR8": (8, 3, True),
           "BGR8Packed": (8, 3, True), "BGRa8": (8, 4, True)}
for _b in (8, 10, 12, 16):
    for _p in ("GR", "RG", "GB", "BG"):
        FORMATS[f"Bayer{_p}{_b}"] = (_b, 0, False)

#: GenTL errors that mean the transport to the camera is gone (unplugged, powered off, its handle closed).
LOST_ERRORS = ("IoException", "InvalidHandleException", "ClosedException", "NotInitializedException")

_RO, _RW = 3, 4  # genicam.genapi.EAccessMode: readable, readable and writable


class _Producers:
    """One ``Harvester`` per set of producer files, shared by the cameras open on it.

    A GenTL producer is a shared library with process-wide state: a second
    ``Harvester`` loading the same ``.cti`` while the first holds it lists no
    devices.  Cameras on the same producers therefore share one, which is
    reset when the last of them closes.  Its device list is read when it is
    loaded and not refreshed while a camera is open: ``Harvester.update()``
    drops the acquirers it has already created, and the open cameras with them.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._open: dict[tuple[str, ...], list[Any]] = {}  # files -> [Harvester, cameras open on it]

    def acquire(self, files: tuple[str, ...]) -> Any:
        with self._lock:
            entry = self._open.get(files)
            if entry is None:
                core = require("harvesters.core", extra="genicam", feature="the genicam camera driver")
                h = core.Harvester()
                try:
                    for f in files:
                        h.add_file(f, check_existence=True, check_validity=True)
                    h.update()
                except BaseException:
                    h.reset()
                    raise
                entry = self._open[files] = [h, 0]
            entry[1] += 1
            return entry[0]

    def release(self, files: tuple[str, ...]) -> None:
        with self._lock:
            entry = self._open.get(files)
            if entry is None:
                return
            entry[1] -= 1
            if entry[1] <= 0:
                del self._open[files]
                entry[0].reset()


PRODUCERS = _Producers()


def producer_files(producer: str | None) -> tuple[str, ...]:
    """The ``.cti`` files to load: ``producer``, else every ``.cti`` in ``GENICAM_GENTL64_PATH``'s folders."""
    if producer:
        return (os.path.abspath(os.path.expanduser(producer)),)
    files: list[str] = []
    for entry in os.environ.get("GENICAM_GENTL64_PATH", "").split(os.pathsep):
        if os.path.isdir(entry):
            files += sorted(glob.glob(os.path.join(entry, "*.cti")))
        elif entry.endswith(".cti") and os.path.isfile(entry):
            files.append(entry)
    return tuple(os.path.abspath(f) for f in dict.fromkeys(files))


def virtual_producer() -> str | None:
    """The ``genicam`` wheel's virtual producer ``viky.cti``, or ``None`` when the wheel is not installed."""
    try:
        import genicam
    except ImportError:
        return None
    path = os.path.join(os.path.dirname(genicam.__file__), "viky.cti")
    return path if os.path.isfile(path) else None


class GenICamCamera(FrameCameraBase):
    """A GenICam camera through a GenTL producer and harvesters; see the module docstring."""

    name = "genicam"

    params = GENICAM

    def __init__(self, *, serial: str | None = None, pixel_format: str | None = None, gain_db: float = 0.0,
                 black_level: float | None = None, trigger: str = "software", timeout_s: float = 5.0,
                 nominal_exposure_s: float | None = None, producer: str | None = None, width: int | None = None,
                 height: int | None = None, buffers: int = 4):
        super().__init__(serial=serial, pixel_format=pixel_format, gain_db=gain_db, black_level=black_level,
                         trigger=trigger, timeout_s=timeout_s, nominal_exposure_s=nominal_exposure_s)
        self._gentl = require("genicam.gentl", extra="genicam", feature="the genicam camera driver")
        self._genapi = require("genicam.genapi", extra="genicam", feature="the genicam camera driver")
        self._files: tuple[str, ...] | None = None
        self._ia: Any = None  # harvesters ImageAcquirer once open
        self._nm: Any = None  # the camera's (remote device's) node map
        self._exposure_node: Any = None
        self._per_frame_start = False  # a free-running camera: acquisition is started for each frame
        self._lost = False
        try:
            self._open(producer, width, height, int(buffers))
        except BaseException:
            self.close()
            raise

    # -- opening -------------------------------------------------------------------------------

    def _open(self, producer: str | None, width: int | None, height: int | None, buffers: int) -> None:
        files = producer_files(producer)
        if producer and not os.path.isfile(files[0]):
            raise self.error(CameraError, f"the GenTL producer {files[0]} does not exist; give the vendor's .cti file")
        if not files:
            viky = virtual_producer()
            raise self.error(CameraError, "no GenTL producer: give producer (the camera vendor's .cti file) or set "
                             "GENICAM_GENTL64_PATH to the folder holding it (it is "
                             f"{os.environ.get('GENICAM_GENTL64_PATH', 'unset')!r})"
                             + (f"; the genicam wheel's virtual producer is {viky}" if viky else ""))
        try:
            h = PRODUCERS.acquire(files)
        except (self._gentl.GenericException, OSError) as e:
            raise self.error(CameraError, f"the GenTL producer {', '.join(files)} could not be loaded: {e}") from None
        self._files = files
        found = list(h.device_info_list)
        chosen = [d for d in found if self.serial is None or _info(d, "serial_number") == str(self.serial)]
        if not chosen:
            listed = [f"{_info(d, 'serial_number')} ({_info(d, 'model')})" for d in found]
            raise self.error(CameraLost, f"no GenICam camera{f' with serial {self.serial}' if self.serial else ''} "
                             f"found through {', '.join(os.path.basename(f) for f in files)} (found {listed or 'none'}); "
                             "check the cable and power, and that the producer is the one for this camera's interface")
        info = chosen[0]
        self.identity = {"vendor": _info(info, "vendor"), "model": _info(info, "model"),
                         "serial": _info(info, "serial_number")}
        try:
            self._ia = h.create(info)
        except (self._gentl.GenericException, ValueError) as e:
            raise self.error(CameraError, f"could not be opened (in use by another program?): {e}") from None
        self._nm = self._ia.remote_device.node_map
        for key, feature in (("vendor", "DeviceVendorName"), ("model", "DeviceModelName"),
                             ("serial", "DeviceSerialNumber")):
            value = self._read(feature)
            if value:
                self.identity[key] = str(value)
        try:
            self._configure(width, height)
            self._ia.num_buffers = buffers
            if not self._per_frame_start:
                self._ia.start()
        except (self._gentl.GenericException, self._genapi.GenericException) as e:
            raise self.error(CameraError, f"could not be configured: {_message(e)}") from None

    def _node(self, name: str, writable: bool = False) -> Any:
        """The feature ``name`` of the camera's node map, or ``None`` when the camera lacks it (or it is read-only
        and ``writable``)."""
        nm = self._nm
        if not nm.has_node(name):
            return None
        node = nm.get_node(name)
        mode = node.node.get_access_mode()
        return node if mode == _RW or (mode == _RO and not writable) else None

    def _read(self, name: str) -> Any:
        node = self._node(name)
        try:
            return None if node is None else node.value
        except self._genapi.GenericException:
            return None

    def _set(self, name: str, value: Any, required: str | None = None) -> bool:
        """Set a feature; a missing one is ``False``, or, when ``required`` says what needs it, an error naming it."""
        node = self._node(name, writable=True)
        if node is None:
            if required:
                raise self.error(CameraError, f"camera {self.identity['model']} has no {name} feature: {required}",
                                 command=f"{name} = {value}")
            return False
        try:
            node.value = value
        except self._genapi.GenericException as e:
            raise self.error(CameraError, f"refused {name} = {value!r}: {_message(e)}", command=f"{name} = {value}") from None
        return True

    def _configure(self, width: int | None, height: int | None) -> None:
        for auto in ("ExposureAuto", "GainAuto", "BalanceWhiteAuto"):
            self._set(auto, "Off")
        if self.pixel_format is not None:
            if self.pixel_format not in FORMATS:
                raise self.error(CameraError, f"pixel format {self.pixel_format!r} is not read by this driver; "
                                 f"choose one of {sorted(FORMATS)}")
            node = self._node("PixelFormat", writable=True)
            offered = list(getattr(node, "symbolics", ()) or ()) if node is not None else []
            if self.pixel_format not in offered:
                raise self.error(CameraError, f"has no pixel format {self.pixel_format!r}; it offers {offered}",
                                 command=f"PixelFormat = {self.pixel_format}")
            self._set("PixelFormat", self.pixel_format, required="the pixel format cannot be chosen")
        self.pixel_format = str(self._read("PixelFormat"))
        if self.pixel_format not in FORMATS:
            raise self.error(CameraError, f"the camera delivers {self.pixel_format}, which this driver does not read; "
                             f"set pixel_format to one of {sorted(FORMATS)}")
        self.bit_depth, self._channels, self._bgr = FORMATS[self.pixel_format]
        for name in ("OffsetX", "OffsetY"):
            self._set(name, 0)
        for name, value in (("Width", width), ("Height", height)):
            if value is not None:
                node = self._node(name, writable=True)
                if node is not None and not node.min <= int(value) <= node.max:
                    raise self.error(CameraError, f"refused {name} = {value}: camera {self.identity['model']} takes "
                                     f"{node.min} to {node.max} px", command=f"{name} = {value}")
                self._set(name, int(value), required="the region of interest cannot be set")
        self.width, self.height = int(self._read("Width") or 0), int(self._read("Height") or 0)
        if not self._set("Gain", float(self.gain_db)) and self.gain_db:
            raise self.error(CameraError, f"camera {self.identity['model']} has no Gain feature: leave gain_db at 0",
                             command="Gain")
        if self.black_level is not None:
            self._set("BlackLevel", float(self.black_level), required="leave black_level unset")
        else:
            level = self._read("BlackLevel")
            self.black_level = None if level is None else float(level)
        self._set("AcquisitionMode", "Continuous")
        can_trigger = self._node("TriggerMode", writable=True) is not None
        if self.trigger == "hardware":
            if not can_trigger:
                raise self.error(CameraError, f"camera {self.identity['model']} has no TriggerMode feature: it cannot "
                                 "wait for a hardware trigger; use trigger: software", command="TriggerMode = On")
            self._set("TriggerSelector", "FrameStart")
            self._set("TriggerMode", "On")
            self._set("TriggerSource", "Line1", required="it cannot take a hardware trigger on Line1")
        elif can_trigger and self._node("TriggerSoftware") is not None:
            self._set("TriggerSelector", "FrameStart")
            self._set("TriggerMode", "On")
            self._set("TriggerSource", "Software", required="it cannot be triggered by software")
        else:
            if can_trigger:
                self._set("TriggerMode", "Off")
            self._per_frame_start = True
        self._exposure_node = self._node("ExposureTime", writable=True) or self._node("ExposureTimeAbs", writable=True)

    # -- FrameCameraBase ----------------------------------------------------------------------

    def _alive(self, command: str) -> None:
        if self._lost or self._ia is None:
            raise self.error(CameraLost, "the camera stopped answering (unplugged, powered off or its link is down)",
                             command=command)

    def _device_range_s(self) -> tuple[float, float] | None:
        self._alive("exposure range")
        n = self._exposure_node
        if n is None:
            if self.nominal_exposure_s is not None:
                return None  # the base class takes the stated fixed exposure
            raise self.error(ExposureRefused, f"camera {self.identity['model']} has no ExposureTime feature: it cannot "
                             "bracket exposures (give nominal_exposure_s, its fixed exposure, to capture at that one "
                             "time)", command="ExposureTime")
        try:
            return float(n.min) * 1e-6, float(n.max) * 1e-6
        except self._genapi.GenericException as e:
            raise self._failure(e, "exposure range") from None

    def _set_exposure(self, exposure_s: float) -> float:
        command = f"ExposureTime = {exposure_s * 1e6:g} us"
        self._alive(command)
        try:
            self._exposure_node.value = float(exposure_s) * 1e6
            return float(self._exposure_node.value) * 1e-6
        except (self._gentl.GenericException, self._genapi.GenericException) as e:
            raise self._failure(e, command) from None

    def _grab(self, timeout_s: float, **_: Any) -> np.ndarray:
        ia = self._ia
        self._alive("trigger and retrieve")
        try:
            if self._per_frame_start:
                ia.start()
            elif self.trigger == "software":
                self._nm.get_node("TriggerSoftware").execute()
            buf = ia.try_fetch(timeout=max(float(timeout_s), 1e-3))
        except (self._gentl.GenericException, self._genapi.GenericException) as e:
            self._stop_per_frame()
            raise self._failure(e, "trigger and retrieve") from None
        if buf is None:
            self._stop_per_frame()
            raise self.error(FrameTimeout, f"no frame within {timeout_s:g} s of the trigger", command="retrieve")
        try:
            c = buf.payload.components[0]
            h, w = int(c.height), int(c.width)
            n = max(self._channels, 1)
            data = np.asarray(c.data)
            dtype = np.uint8 if self.bit_depth == 8 else np.uint16
            if data.dtype != dtype:
                data = data.astype(dtype)
            row = data.size // h if h else 0  # a producer may pad rows
            frame = data[: h * row].reshape(h, row)[:, : w * n]
            frame = frame.reshape(h, w, n) if n > 1 else frame.reshape(h, w)
            if self._bgr:
                frame = frame[..., 2::-1] if n == 4 else frame[..., ::-1]
            if self._channels == 0:
                from .pylon import _demosaic

                frame = _demosaic(np.ascontiguousarray(frame), str(self.pixel_format)[5:7])
            return np.array(frame, copy=True)
        finally:
            buf.queue()
            self._stop_per_frame()

    def _stop_per_frame(self) -> None:
        if self._per_frame_start and self._ia is not None and not self._lost:
            try:
                self._ia.stop()
            except (self._gentl.GenericException, self._genapi.GenericException):
                pass  # the error that brought us here is the one reported

    def _failure(self, e: Exception, command: str) -> CameraError:
        if type(e).__name__ in LOST_ERRORS:
            self._lost = True
            return self.error(CameraLost, f"the camera stopped answering: {_message(e)}", command=command)
        if isinstance(e, self._gentl.TimeoutException | self._genapi.TimeoutException):
            return self.error(FrameTimeout, f"timed out: {_message(e)}", command=command)
        return self.error(CameraError, _message(e), command=command)

    def _close(self) -> None:
        ia, self._ia, self._nm, self._exposure_node = self._ia, None, None, None
        files, self._files = self._files, None
        try:
            if ia is not None:
                try:
                    if ia.is_acquiring():
                        ia.stop()
                finally:
                    ia.destroy()
        finally:
            if files is not None:
                PRODUCERS.release(files)


def _info(device_info: Any, key: str) -> str:
    """A field of a producer's device list entry; ``""`` when the producer does not supply it."""
    try:
        return str(getattr(device_info, key) or "")
    except Exception:  # noqa: BLE001 - genicam raises NotAvailableException for fields a producer lacks
        return ""


def _message(e: Exception) -> str:
    """A GenICam exception's message without the C++ file and line it was thrown at."""
    text = str(e).strip() or type(e).__name__
    return text.split(" : ")[0] if " : " in text else text
