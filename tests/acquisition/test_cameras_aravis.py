"""The ``aravis`` frame camera against Aravis's GigE Vision camera simulator on the loopback interface.

``arv-fake-gv-camera-0.8`` (Debian's ``aravis-tools``) is started for the
module; the driver finds it by its serial number over GigE Vision, as it
would a camera on the network.  One simulator at a time can hold the GigE
Vision control port, so the test that unplugs it (kills it) comes last.  Skipped where the simulator or the Aravis
introspection data (``gir1.2-aravis-0.8`` and PyGObject) is missing.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time

import numpy as np
import pytest

from sbrdf_core.testing import CameraTests
from sbrdf_lib.camera import CameraLost

FAKE = "arv-fake-gv-camera-0.8"
SERIAL = "SBRDF-TEST"

if shutil.which(FAKE) is None:
    pytest.skip(f"{FAKE} is not installed (apt install aravis-tools)", allow_module_level=True)
gi = pytest.importorskip("gi")
try:
    gi.require_version("Aravis", "0.8")
except ValueError:
    pytest.skip("no Aravis 0.8 introspection data (apt install gir1.2-aravis-0.8)", allow_module_level=True)


def start_fake(serial: str) -> subprocess.Popen:
    proc = subprocess.Popen([FAKE, "-i", "127.0.0.1", "-s", serial], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    from gi.repository import Aravis

    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and proc.poll() is None:
        Aravis.update_device_list()
        if any(Aravis.get_device_serial_nbr(i) == serial for i in range(Aravis.get_n_devices())):
            return proc
        time.sleep(0.1)
    proc.kill()
    pytest.skip(f"{FAKE} did not appear on the loopback interface (another one running holds its port?)")


@pytest.fixture(scope="module")
def fake_process():
    proc = start_fake(SERIAL)
    yield proc
    if proc.poll() is None:
        proc.terminate()
        proc.wait(5)


@pytest.fixture
def fake_camera(fake_process):
    if fake_process.poll() is not None:
        pytest.skip("the simulator was unplugged by an earlier test")
    return SERIAL


class TestAravisConformance(CameraTests):
    name = "aravis"
    params = {"serial": SERIAL, "pixel_format": "Mono16", "width": 64, "height": 48}

    @pytest.fixture(autouse=True)
    def _fake(self, fake_camera):
        return fake_camera


def test_exposure_bracket_through_the_cameras_own_exposure_control(fake_camera, registry):
    """Each bracket time is set on the camera and read back; the frames brighten with it."""
    cam = registry.create("device", "aravis", {"serial": fake_camera, "pixel_format": "Mono8"})
    try:
        info = cam.info()
        assert (info["vendor"], info["model"], info["serial"]) == ("Aravis", "Fake", fake_camera)
        assert info["white_balance"] == "off" and info["trigger"] == "software"
        means = []
        for t in (0.005, 0.01, 0.02):
            assert cam.set_exposure(t) == pytest.approx(t, rel=1e-3)
            means.append(float(cam.grab().mean()))
        assert means[0] < means[1] < means[2], means
    finally:
        cam.close()


def test_a_gonio_capture_through_the_fake_camera(fake_camera, tmp_path, registry):
    """The rig (pty motor simulators) with the aravis driver: brackets set on the camera, the device recorded."""
    from .test_gonio import ANGLES, motors

    cam = registry.create("device", "virtual-camera", {"width": 64, "height": 48, "focal_px": 200.0})
    store, folder = tmp_path / "store", tmp_path / "scan"
    params = {"path": str(folder), "motors": motors(), "plan": {"angles_deg": ANGLES[:3]},
              "exposures": {"times_s": [0.005, 0.02]}, "durable": False, "read": {"response": "linear"},
              "camera": {"device": "aravis", "params": {"serial": fake_camera, "pixel_format": "Mono8", "width": 64,
                                                         "height": 48}},
              "sample": cam.sample_info(), "intrinsics": {"K": cam.K.tolist(), "dist": cam.dist.tolist()}}
    g = tmp_path / "g.yaml"
    g.write_text(json.dumps({"name": "g", "store": str(store),
                             "nodes": {"capture": {"kind": "Capture", "plugin": "gonio", "params": params}}}))
    from sbrdf_core.runner import run_graph
    from sbrdf_lib.capture_folder import load_manifest

    run_graph(str(g))
    m = load_manifest(folder)
    assert m.complete and len(m.poses) == 3
    assert m.camera.extra["device"]["driver"] == "aravis" and m.camera.extra["device"]["serial"] == fake_camera
    for pose in m.poses:
        assert [e.time_s for e in pose.exposures] == pytest.approx([0.005, 0.02], rel=1e-3)


def test_no_camera_with_that_serial_names_what_was_found(fake_camera, registry):
    with pytest.raises(CameraLost, match="no GenICam camera with serial NOPE"):
        registry.create("device", "aravis", {"serial": "NOPE"})


def test_mono_frames_repeat_the_code_in_every_channel(fake_camera, registry):
    cam = registry.create("device", "aravis", {"serial": fake_camera, "pixel_format": "Mono16", "width": 32,
                                               "height": 16})
    try:
        cam.set_exposure(0.01)
        f = cam.grab()
        assert f.shape == (16, 32, 3) and f.dtype == np.uint16
        assert (f[..., 0] == f[..., 1]).all() and (f[..., 1] == f[..., 2]).all()
    finally:
        cam.close()


def test_a_camera_that_stops_answering_is_lost(fake_process, fake_camera, registry):
    """Last: the simulator is killed, as a camera is unplugged."""
    cam = registry.create("device", "aravis", {"serial": fake_camera, "pixel_format": "Mono8", "timeout_s": 1.0})
    try:
        cam.set_exposure(0.01)
        assert cam.grab().shape[2] == 3
        fake_process.kill()
        fake_process.wait(5)
        with pytest.raises(CameraLost, match=fake_camera):
            cam.set_exposure(0.02)
            cam.grab()
    finally:
        cam.close()
