"""The ``genicam`` frame camera (harvesters) against the ``genicam`` wheel's virtual GenTL producer, ``viky.cti``.

``viky.cti`` lists three virtual cameras (serials 0, 1, 2: a ball bouncing
on white, drawn in red, green or blue) with ``Width``, ``Height``,
``PixelFormat`` (``RGBa8``, ``Mono8``) and ``AcquisitionFrameRate``, and
nothing else of the SFNC: no ``ExposureTime``, ``Gain``, ``BlackLevel``,
``TriggerMode`` or ``TriggerSoftware``, no ``DeviceSerialNumber``.  So these
tests check discovery, configuration, frames, identity, the refusals of what
the camera lacks, the frame timeout and a lost camera; they cannot check
exposure control, gain, black level or triggering.

Of the ``CameraTests`` conformance suite, two tests need exposure control and
cannot run on viky as the contract means them:
``test_frames_are_full_scale_rgb_codes_of_the_declared_size`` (it sets an
exposure first) and
``test_an_exposure_outside_the_range_is_refused_before_the_camera_sees_it``
(it reads the camera's exposure range).  They are skipped in
:class:`TestGenICamConformance`; :class:`TestGenICamFixedExposureConformance`
runs them with ``nominal_exposure_s``, the contract's path for a camera
without exposure control, which checks the frames and the refusal but not an
``ExposureTime`` feature.

Skipped where harvesters or the virtual producer is missing (``pip install
'sbrdf[genicam]'``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("harvesters.core", reason="harvesters is not installed: pip install 'sbrdf[genicam]'")

from sbrdf_core.testing import CameraTests  # noqa: E402
from sbrdf_devices.cameras.genicam import virtual_producer  # noqa: E402
from sbrdf_lib.camera import CameraError, CameraLost, ExposureRefused, FrameTimeout  # noqa: E402

VIKY = virtual_producer()
if VIKY is None:
    pytest.skip("the genicam wheel's virtual producer viky.cti is missing: pip install 'sbrdf[genicam]'",
                allow_module_level=True)

NO_EXPOSURE_CONTROL = ("viky.cti's cameras have no ExposureTime feature, so this contract test (which sets or reads "
                       "the camera's exposure) cannot run on them; TestGenICamFixedExposureConformance runs it with "
                       "nominal_exposure_s")
MONO = {"producer": VIKY, "serial": "1", "pixel_format": "Mono8", "width": 160, "height": 120}


class TestGenICamConformance(CameraTests):
    name = "genicam"
    params = MONO

    def test_frames_are_full_scale_rgb_codes_of_the_declared_size(self):
        pytest.skip(NO_EXPOSURE_CONTROL)

    def test_an_exposure_outside_the_range_is_refused_before_the_camera_sees_it(self):
        pytest.skip(NO_EXPOSURE_CONTROL)


class TestGenICamFixedExposureConformance(CameraTests):
    """The whole suite on a camera without exposure control, its fixed exposure stated."""

    name = "genicam"
    params = {**MONO, "nominal_exposure_s": 0.05}
    exposure_s = 0.05


def open_camera(registry, **params):
    return registry.create("device", "genicam", {"producer": VIKY, **params})


def test_the_producer_lists_its_cameras_and_each_is_found_by_serial(registry):
    for serial in ("0", "1", "2"):
        cam = open_camera(registry, serial=serial)
        try:
            info = cam.info()
            assert (info["vendor"], info["model"], info["serial"]) == ("Machine Vision Games Ltd.", "Viky", serial)
            assert info["driver"] == "genicam" and info["white_balance"] == "off"
        finally:
            cam.close()


def test_no_camera_with_that_serial_names_what_the_producer_lists(registry):
    with pytest.raises(CameraLost, match=r"no GenICam camera with serial NOPE found through viky.cti "
                                         r"\(found \['0 \(Viky\)', '1 \(Viky\)', '2 \(Viky\)'\]\)"):
        open_camera(registry, serial="NOPE")


def test_frames_have_the_declared_size_and_dtype_in_rgb_order(registry):
    """RGBa8 (the default) loses its alpha; the blue camera's ball is blue, so the channels are not swapped."""
    cam = open_camera(registry, serial="2", nominal_exposure_s=0.05)
    try:
        info = cam.info()
        assert (info["pixel_format"], info["bit_depth"], info["width"], info["height"]) == ("RGBa8", 8, 400, 400)
        f = cam.grab()
        assert f.shape == (400, 400, 3) and f.dtype == np.uint8
        assert (f[..., 2] >= f[..., 0]).all() and (f[..., 2] > f[..., 0]).any()
    finally:
        cam.close()


def test_mono_frames_of_a_region_repeat_the_code_in_every_channel(registry):
    cam = open_camera(registry, **{**MONO, "width": 200, "height": 100})
    try:
        f = cam.grab()
        assert f.shape == (100, 200, 3) and f.dtype == np.uint8
        assert (f[..., 0] == f[..., 1]).all() and (f[..., 1] == f[..., 2]).all()
    finally:
        cam.close()


def test_a_camera_without_exposure_time_cannot_bracket_and_says_so(registry):
    cam = open_camera(registry, serial="0")
    try:
        for call in (cam.exposure_range_s, lambda: cam.set_exposure(0.01)):
            with pytest.raises(ExposureRefused, match="camera Viky has no ExposureTime feature: it cannot bracket "
                                                      "exposures"):
                call()
    finally:
        cam.close()


def test_a_camera_without_exposure_time_is_refused_before_any_motion(tmp_path, registry, start_simulator):
    """The gonio plan asks for a bracket: refused at the exposure check, the motors where they were."""
    from sbrdf_capture.gonio import GonioCaptureError
    from sbrdf_core.runner import run_graph
    from sbrdf_devices.motors.sim import SimulatedIndexer, SimulatedPTU

    from .test_gonio import ANGLES, motors

    sims = {"pan": start_simulator(SimulatedPTU), "tilt_roll": start_simulator(SimulatedPTU),
            "light": start_simulator(SimulatedIndexer)}
    virtual = registry.create("device", "virtual-camera", {"width": 64, "height": 48, "focal_px": 200.0})
    folder = tmp_path / "scan"
    params = {"path": str(folder), "motors": motors(sims["pan"].port, sims["tilt_roll"].port, sims["light"].port),
              "plan": {"angles_deg": ANGLES[1:3]}, "exposures": {"times_s": [0.005, 0.02]}, "durable": False,
              "camera": {"device": "genicam", "params": MONO},
              "sample": virtual.sample_info(), "intrinsics": {"K": virtual.K.tolist(), "dist": virtual.dist.tolist()}}
    g = tmp_path / "g.yaml"
    g.write_text(json.dumps({"name": "g", "store": str(tmp_path / "store"),
                             "nodes": {"capture": {"kind": "Capture", "plugin": "gonio", "params": params}}}))
    before = (sims["pan"].position_deg("pan"), sims["tilt_roll"].position_deg("tilt"), sims["light"].position_deg(1))
    with pytest.raises(GonioCaptureError) as err:
        run_graph(str(g))
    assert isinstance(err.value.cause, ExposureRefused) and "before any motion" in str(err.value)
    assert "camera Viky has no ExposureTime feature: it cannot bracket exposures" in str(err.value)
    assert (sims["pan"].position_deg("pan"), sims["tilt_roll"].position_deg("tilt"),
            sims["light"].position_deg(1)) == before
    assert not (folder / "images").exists() or not any((folder / "images").iterdir())


@pytest.mark.parametrize("params, message", [
    ({"gain_db": 6.0}, "camera Viky has no Gain feature: leave gain_db at 0"),
    ({"black_level": 16.0}, "camera Viky has no BlackLevel feature: leave black_level unset"),
    ({"trigger": "hardware"}, "camera Viky has no TriggerMode feature: it cannot wait for a hardware trigger"),
    ({"width": 64}, r"refused Width = 64: camera Viky takes 100 to 800 px"),
    ({"pixel_format": "Mono12"}, r"has no pixel format 'Mono12'; it offers \['RGBa8', 'Mono8'\]"),
])
def test_a_setting_the_camera_cannot_take_names_the_feature(registry, params, message):
    with pytest.raises(CameraError, match=message):
        open_camera(registry, serial="0", **params)


def test_a_frame_that_does_not_come_in_time_is_a_frame_timeout(registry):
    """At one frame per second the first frame after the (per-frame) acquisition start is ~1 s away."""
    cam = open_camera(registry, **MONO)
    try:
        cam._node("AcquisitionFrameRate", writable=True).value = 1.0
        with pytest.raises(FrameTimeout, match="no frame within"):
            cam.grab(timeout_s=0.05)
        assert cam.grab(timeout_s=5.0).shape == (120, 160, 3)  # and the camera recovers
    finally:
        cam.close()


def test_a_camera_whose_transport_closes_is_lost(registry):
    """The device's GenTL handle closed under the driver, as an unplugged camera's is."""
    cam = open_camera(registry, **MONO)
    try:
        cam.grab()
        cam._ia.device.module.close()
        with pytest.raises(CameraLost, match="stopped answering"):
            cam.grab()
        with pytest.raises(CameraLost):
            cam.grab()
    finally:
        cam.close()


def test_cameras_on_one_producer_open_together(registry):
    """One Harvester per producer is shared: a second would list no devices while the first holds the .cti."""
    a = open_camera(registry, serial="0", pixel_format="Mono8", width=100, height=100)
    b = open_camera(registry, serial="1", pixel_format="Mono8", width=100, height=100)
    try:
        assert a.grab().shape == b.grab().shape == (100, 100, 3)
        assert (a.info()["serial"], b.info()["serial"]) == ("0", "1")
    finally:
        a.close()
        b.close()
    c = open_camera(registry, serial="2")  # and the producer is loaded afresh once both are closed
    c.close()


def test_the_producer_comes_from_genicam_gentl64_path_when_not_given(registry, monkeypatch):
    import os

    monkeypatch.setenv("GENICAM_GENTL64_PATH", os.path.dirname(VIKY))
    cam = registry.create("device", "genicam", {"serial": "2"})
    try:
        assert cam.info()["serial"] == "2"
    finally:
        cam.close()
    monkeypatch.delenv("GENICAM_GENTL64_PATH")
    with pytest.raises(CameraError, match="no GenTL producer: give producer .* or set GENICAM_GENTL64_PATH"):
        registry.create("device", "genicam", {})
    with pytest.raises(CameraError, match="the GenTL producer /no/such/vendor.cti does not exist"):
        registry.create("device", "genicam", {"producer": "/no/such/vendor.cti"})


def test_a_gonio_capture_through_a_virtual_genicam_camera(tmp_path, registry):
    """The rig (pty motor simulators) with the genicam driver at the camera's stated fixed exposure."""
    from sbrdf_core.runner import run_graph
    from sbrdf_lib.capture_folder import load_manifest

    from .test_gonio import ANGLES, motors

    virtual = registry.create("device", "virtual-camera", {"width": 160, "height": 120, "focal_px": 400.0})
    folder = tmp_path / "scan"
    params = {"path": str(folder), "motors": motors(), "plan": {"angles_deg": ANGLES[:3]},
              "exposures": {"times_s": [0.05]}, "durable": False, "read": {"response": "linear"},
              "camera": {"device": "genicam", "params": {**MONO, "nominal_exposure_s": 0.05}},
              "sample": virtual.sample_info(), "intrinsics": {"K": virtual.K.tolist(), "dist": virtual.dist.tolist()}}
    g = tmp_path / "g.yaml"
    g.write_text(json.dumps({"name": "g", "store": str(tmp_path / "store"),
                             "nodes": {"capture": {"kind": "Capture", "plugin": "gonio", "params": params}}}))
    run_graph(str(g))
    m = load_manifest(folder)
    assert m.complete and len(m.poses) == 3
    device = m.camera.extra["device"]
    assert (device["driver"], device["vendor"], device["model"], device["serial"]) == (
        "genicam", "Machine Vision Games Ltd.", "Viky", "1")
    assert all([e.time_s for e in p.exposures] == [0.05] for p in m.poses)


def test_without_harvesters_the_error_gives_the_install_command(registry, monkeypatch):
    import sys

    for module in ("genicam", "genicam.gentl", "genicam.genapi", "harvesters", "harvesters.core"):
        monkeypatch.setitem(sys.modules, module, None)
    with pytest.raises(ImportError, match=r"pip install 'sbrdf\[genicam\]'"):
        registry.create("device", "genicam", {"producer": VIKY})
