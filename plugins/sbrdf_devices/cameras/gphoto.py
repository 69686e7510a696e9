"""gphoto: DSLRs and mirrorless cameras over USB (PTP) through ``python-gphoto2``.

============================  ======  ===========================================================
parameter                     type    meaning (default)
============================  ======  ===========================================================
``serial``                    str     serial number (``serialnumber`` config); the first camera
                                      found when unset (none)
``pixel_format``              str     recorded: the image format is the camera's ``imageformat``
                                      setting; JPEG and TIFF are decoded (none)
``gain_db``                   float   must stay 0: a DSLR's gain is its ISO, set with ``iso`` (0)
``black_level``               float   must stay unset: a DSLR has no black level setting (none)
``trigger``                   str     ``software``: ``capture`` per frame (a USB release) (software)
``timeout_s``                 float   frame timeout after the exposure, s (30)
``nominal_exposure_s``        float   unused: a DSLR's shutter speeds are its exposure control
``iso``                       str     ISO setting, one of the camera's choices (its own)
``keep_on_camera``            bool    leave each file on the card after downloading it (false)
============================  ======  ===========================================================

Exposure goes through the camera's ``shutterspeed`` choices (``"1/125"``,
``"0.5"``, ``"30"``): the nearest one within a sixth of a stop is set and its
time returned; a time with no choice that close, or ``bulb``, is
:class:`~sbrdf_lib.camera.ExposureRefused`.  White balance is set to the
camera's ``Daylight`` (fixed; auto white balance changes per frame).  A
capture is ``Camera.capture``, then the file is downloaded and decoded; JPEG
files are 8-bit and gamma-encoded (``linear`` false: the response is
recovered from brackets), 16-bit TIFF is read as delivered.  The image size
is the ``imagesize`` setting, or, for a camera without one, that of a frame
the driver takes when it opens.  libgphoto2's
errors map onto the camera errors: the device gone (``GP_ERROR_IO_USB_FIND``,
``GP_ERROR_MODEL_NOT_FOUND``, ``GP_ERROR_IO``) is
:class:`~sbrdf_lib.camera.CameraLost`, ``GP_ERROR_TIMEOUT`` a
:class:`~sbrdf_lib.camera.FrameTimeout`.

No emulator ships in the wheels (libgphoto2's virtual camera is not built
into them), so the tests run this driver against a stand-in for the
``gphoto2`` module at the library seam.

Install: ``pip install 'sbrdf[gphoto]'`` (the wheels bundle libgphoto2).
"""

from __future__ import annotations

import math
from fractions import Fraction
from typing import Any

import numpy as np

from sbrdf_core.errors import ParameterError
from sbrdf_core.extras import require
from sbrdf_lib.camera import CameraError, CameraLost, ExposureRefused, FrameCameraBase, FrameTimeout

from ..declarations import GPHOTO

#: libgphoto2 result codes (gphoto2/gphoto2-port-result.h) meaning the camera is gone.
LOST_CODES = {-7, -52, -53, -105}  # GP_ERROR_IO, _IO_USB_FIND, _IO_USB_CLAIM, GP_ERROR_MODEL_NOT_FOUND
TIMEOUT_CODE = -10  # GP_ERROR_TIMEOUT
#: Largest ratio between a requested time and the shutter speed chosen for it (a sixth of a stop).
SHUTTER_TOLERANCE = 2 ** (1 / 6)


def shutter_seconds(choice: str) -> float | None:
    """``"1/125"`` -> 0.008, ``"0.5"`` / ``"2s"`` -> seconds; ``None`` for ``bulb`` and anything else."""
    text = choice.strip().lower().rstrip("s").strip()
    try:
        value = float(Fraction(text))
    except (ValueError, ZeroDivisionError):
        return None
    return value if value > 0 else None


class GPhotoCamera(FrameCameraBase):
    """A camera driven by libgphoto2; see the module docstring."""

    name = "gphoto"

    params = GPHOTO

    def __init__(self, *, serial: str | None = None, pixel_format: str | None = None, gain_db: float = 0.0,
                 black_level: float | None = None, trigger: str = "software", timeout_s: float = 30.0,
                 nominal_exposure_s: float | None = None, iso: str | None = None, keep_on_camera: bool = False):
        super().__init__(serial=serial, pixel_format=pixel_format, gain_db=gain_db, black_level=black_level,
                         trigger=trigger, timeout_s=timeout_s, nominal_exposure_s=nominal_exposure_s)
        if gain_db:
            raise ParameterError("gphoto: gain_db must be 0: a DSLR's gain is its ISO; set iso")
        if black_level is not None:
            raise ParameterError("gphoto: a DSLR has no black level setting; leave black_level unset")
        if trigger != "software":
            raise ParameterError("gphoto: trigger: hardware is a wired release, which libgphoto2 cannot wait for; "
                                 "use trigger: software")
        self.iso, self.keep_on_camera, self.bit_depth, self.linear = iso, bool(keep_on_camera), 8, False
        self.gp = require("gphoto2", extra="gphoto", feature="the gphoto camera driver")
        self._camera: Any = None  # a gphoto2.Camera while open (the gphoto2 bindings ship no type information)
        self._shutter: list[tuple[float, str]] = []
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def _failure(self, e: Exception, command: str) -> CameraError:
        code = getattr(e, "code", None)
        if code in LOST_CODES:
            return self.error(CameraLost, f"the camera disappeared (unplugged, switched off or asleep): {e}",
                              command=command)
        if code == TIMEOUT_CODE:
            return self.error(FrameTimeout, f"timed out: {e}", command=command)
        return self.error(CameraError, str(e), command=command)

    def _call(self, command: str, fn, *args):
        try:
            return fn(*args)
        except self.gp.GPhoto2Error as e:
            raise self._failure(e, command) from e

    def _open(self) -> None:
        gp = self.gp
        self._camera = gp.Camera()
        self._call("init", self._camera.init)
        config = self._call("get_config", self._camera.get_config)
        found = self._value(config, "serialnumber") or ""
        if self.serial is not None and found != self.serial:
            raise self.error(CameraLost, f"the camera found has serial {found!r}, not {self.serial!r}")
        abilities = self._call("get_abilities", self._camera.get_abilities)
        self.identity = {"vendor": self._value(config, "manufacturer") or "", "model": abilities.model,
                         "serial": found}
        self.pixel_format = self._value(config, "imageformat") or self.pixel_format or "camera"
        shutter = self._widget(config, "shutterspeed")
        if shutter is None:
            raise self.error(CameraError, "has no shutterspeed setting (is it in manual or shutter priority mode?)")
        self._shutter = sorted((s, c) for c in shutter.get_choices() if (s := shutter_seconds(c)) is not None)
        changes = {"whitebalance": "Daylight"}
        if self.iso is not None:
            changes["iso"] = self.iso
        for name, value in changes.items():
            widget = self._widget(config, name)
            if widget is None:
                continue
            choices = list(widget.get_choices())
            if value not in choices:
                if name == "iso":
                    raise self.error(CameraError, f"iso {value!r} is not one of the camera's {choices}")
                continue
            widget.set_value(value)
        self._call("set_config", self._camera.set_config, config)
        size = (self._value(config, "imagesize") or "").lower().split("x")
        if len(size) == 2 and all(v.strip().isdigit() for v in size):
            self.width, self.height = int(size[0]), int(size[1])
        else:  # the capture folder's header needs the size before the first pose: one frame tells it
            self.set_exposure(self._shutter[len(self._shutter) // 2][0])
            self.grab()

    @staticmethod
    def _widget(config, name: str):
        try:
            return config.get_child_by_name(name)
        except Exception:  # noqa: BLE001 - python-gphoto2 raises GPhoto2Error for a missing child
            return None

    def _value(self, config, name: str) -> str | None:
        w = self._widget(config, name)
        return None if w is None else str(w.get_value())

    # -- FrameCameraBase ----------------------------------------------------------------------

    def _device_range_s(self) -> tuple[float, float] | None:
        return (self._shutter[0][0], self._shutter[-1][0]) if self._shutter else None

    def _set_exposure(self, exposure_s: float) -> float:
        seconds, choice = min(self._shutter, key=lambda sc: abs(math.log(sc[0] / exposure_s)))
        if max(seconds / exposure_s, exposure_s / seconds) > SHUTTER_TOLERANCE:
            raise self.error(ExposureRefused, f"no shutter speed within a sixth of a stop of {exposure_s:g} s (nearest "
                             f"{choice})", command=f"shutterspeed {exposure_s:g} s")
        config = self._call("get_config", self._camera.get_config)
        self._widget(config, "shutterspeed").set_value(choice)
        self._call(f"shutterspeed = {choice}", self._camera.set_config, config)
        return seconds

    def _grab(self, timeout_s: float, **_: Any) -> np.ndarray:
        import cv2

        gp = self.gp
        path = self._call("capture", self._camera.capture, gp.GP_CAPTURE_IMAGE)
        where = f"{path.folder}/{path.name}"
        file = self._call(f"download {where}", self._camera.file_get, path.folder, path.name, gp.GP_FILE_TYPE_NORMAL)
        data = memoryview(file.get_data_and_size())
        if not self.keep_on_camera:
            self._call(f"delete {where}", self._camera.file_delete, path.folder, path.name)
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise self.error(CameraError, f"{where}: not a JPEG or TIFF file (raw files need the camera set to "
                             "JPEG or TIFF)", command=f"decode {where}")
        if image.ndim == 3:
            image = image[..., 2::-1]  # BGR(A) -> RGB
        self.bit_depth = 16 if image.dtype == np.uint16 else 8
        self.height, self.width = image.shape[:2]
        return image

    def _close(self) -> None:
        cam, self._camera = self._camera, None
        if cam is not None:
            cam.exit()
