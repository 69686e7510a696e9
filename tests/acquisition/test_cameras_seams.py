"""The ``uvc`` driver on an image sequence and the ``gphoto`` driver at the libgphoto2 seam.

OpenCV's ``VideoCapture`` reads a numbered image sequence exactly as it
reads a device, so the ``uvc`` driver runs unchanged on files.  No emulator
of libgphoto2 ships in the ``gphoto2`` wheels, so :class:`FakeGPhoto2`
stands in for the ``gphoto2`` module (the library seam: the calls
python-gphoto2 exposes, with its error codes); the driver above it is the
production code, and the conformance suite is the same as for pylon.
"""

from __future__ import annotations

import sys
import types

import cv2
import numpy as np
import pytest

from sbrdf_core.errors import ParameterError
from sbrdf_core.testing import CameraTests
from sbrdf_lib.camera import CameraLost, ExposureRefused, FrameTimeout

# -- uvc -----------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    d = tmp_path_factory.mktemp("uvc")
    for i in range(4):
        cv2.imwrite(str(d / f"f{i:03d}.png"), np.full((24, 32, 3), (10 * i, 20 * i, 30 * i), np.uint8))
    return str(d / "f%03d.png")


class TestUVCConformance(CameraTests):
    name = "uvc"

    @pytest.fixture(autouse=True)
    def _source(self, sequence):
        self.params = {"source": sequence, "nominal_exposure_s": self.exposure_s}


def test_uvc_reads_the_sequence_as_rgb_frames_in_order(registry, sequence):
    cam = registry.create("device", "uvc", {"source": sequence, "nominal_exposure_s": 0.02})
    assert cam.exposure_range_s() == (0.02, 0.02) and cam.info()["linear"] is False
    frames = [cam.grab() for _ in range(4)]
    assert [tuple(f[0, 0]) for f in frames] == [(30 * i, 20 * i, 10 * i) for i in range(4)]  # BGR file -> RGB
    with pytest.raises(CameraLost, match="no more frames"):
        cam.grab()
    with pytest.raises(ExposureRefused):
        cam.set_exposure(0.04)
    cam.close()


def test_uvc_refuses_what_a_uvc_camera_cannot_do(registry, sequence):
    with pytest.raises(ParameterError, match="nominal_exposure_s"):
        registry.create("device", "uvc", {"source": sequence})
    with pytest.raises(ParameterError, match="dB"):
        registry.create("device", "uvc", {"source": sequence, "nominal_exposure_s": 0.01, "gain_db": 6.0})


# -- gphoto at the library seam --------------------------------------------------------------------------------


class GPhoto2Error(Exception):
    def __init__(self, code: int):
        super().__init__(f"[{code}] gphoto2 error")
        self.code = code


class Widget:
    def __init__(self, name, value=None, choices=()):
        self.name, self.value, self.choices, self.children = name, value, list(choices), {}

    def get_child_by_name(self, name):
        if name not in self.children:
            raise GPhoto2Error(-2)
        return self.children[name]

    def get_value(self):
        return self.value

    def set_value(self, value):
        if self.choices and value not in self.choices:
            raise GPhoto2Error(-2)
        self.value = value

    def get_choices(self):
        return iter(self.choices)


class FakeCamera:
    """A DSLR as libgphoto2 shows it: a config tree, capture to the card, download, delete."""

    SHUTTER = ["bulb", "30", "1", "1/2", "1/4", "1/8", "1/15", "1/30", "1/60", "1/125", "1/250", "1/500"]
    #: Class-level fault script: capture number -> libgphoto2 error code raised instead.
    faults: dict[int, int] = {}
    captures = 0

    def init(self):
        cfg = Widget("main")
        for w in (Widget("serialnumber", "0123456789"), Widget("manufacturer", "Canon Inc."),
                  Widget("shutterspeed", "1/60", self.SHUTTER), Widget("iso", "Auto", ["Auto", "100", "200"]),
                  Widget("whitebalance", "Auto", ["Auto", "Daylight", "Tungsten"]), Widget("imagesize", "64x48"),
                  Widget("imageformat", "Large Fine JPEG")):
            cfg.children[w.name] = w
        self.config, self.card = cfg, {}

    def get_config(self):
        return self.config

    def set_config(self, config):
        self.config = config

    def get_abilities(self):
        return types.SimpleNamespace(model="Canon EOS 5D Mark IV")

    def capture(self, kind):
        FakeCamera.captures += 1
        code = self.faults.get(FakeCamera.captures)
        if code is not None:
            raise GPhoto2Error(code)
        from fractions import Fraction

        t = float(Fraction(self.config.children["shutterspeed"].value))
        value = min(255, int(round(t * 2000)))
        name = f"IMG_{FakeCamera.captures:04d}.JPG"
        self.card[name] = cv2.imencode(".png", np.full((48, 64, 3), value, np.uint8))[1].tobytes()
        return types.SimpleNamespace(folder="/store_00020001/DCIM/100CANON", name=name)

    def file_get(self, folder, name, kind):
        data = self.card[name]
        return types.SimpleNamespace(get_data_and_size=lambda: data)

    def file_delete(self, folder, name):
        del self.card[name]

    def exit(self):
        pass


@pytest.fixture
def fake_gphoto2(monkeypatch):
    mod = types.ModuleType("gphoto2")
    mod.GPhoto2Error, mod.Camera = GPhoto2Error, FakeCamera
    mod.GP_CAPTURE_IMAGE, mod.GP_FILE_TYPE_NORMAL = 0, 1
    monkeypatch.setitem(sys.modules, "gphoto2", mod)
    monkeypatch.setattr(FakeCamera, "faults", {})
    monkeypatch.setattr(FakeCamera, "captures", 0)
    return mod


class TestGPhotoConformance(CameraTests):
    name = "gphoto"
    exposure_s = 1 / 60

    @pytest.fixture(autouse=True)
    def _seam(self, fake_gphoto2):
        pass


def test_gphoto_sets_the_nearest_shutter_speed_and_settings(registry, fake_gphoto2):
    cam = registry.create("device", "gphoto", {"iso": "100"})
    info = cam.info()
    assert (info["vendor"], info["model"], info["serial"]) == ("Canon Inc.", "Canon EOS 5D Mark IV", "0123456789")
    assert (info["width"], info["height"], info["linear"]) == (64, 48, False)
    config = cam._camera.config.children
    assert config["iso"].value == "100" and config["whitebalance"].value == "Daylight"
    assert cam.exposure_range_s() == (1 / 500, 30.0)
    assert cam.set_exposure(0.0167) == pytest.approx(1 / 60) and config["shutterspeed"].value == "1/60"
    frame = cam.grab()
    assert frame.shape == (48, 64, 3) and frame[0, 0, 0] == round(2000 / 60)
    assert cam._camera.card == {}  # downloaded, then deleted from the card
    with pytest.raises(ExposureRefused, match="sixth of a stop"):
        cam.set_exposure(3.0)  # between 1 s and 30 s: no speed near it
    cam.close()


@pytest.mark.parametrize("code,error", [(-52, CameraLost), (-105, CameraLost), (-10, FrameTimeout)])
def test_gphoto_library_errors_become_camera_errors(registry, fake_gphoto2, code, error):
    cam = registry.create("device", "gphoto", {})
    FakeCamera.faults = {FakeCamera.captures + 2: code}
    cam.grab()
    with pytest.raises(error) as err:
        cam.grab()
    assert "0123456789" in str(err.value) and "capture" in str(err.value)
    cam.close()


def test_gphoto_missing_library_names_the_extra(registry, monkeypatch):
    monkeypatch.setitem(sys.modules, "gphoto2", None)
    with pytest.raises(ImportError, match=r"pip install 'sbrdf\[gphoto\]'"):
        registry.create("device", "gphoto", {})
