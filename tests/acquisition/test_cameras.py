"""The ``pylon`` frame camera against Basler's emulator, alone and driving the ``gonio`` capture.

Nothing of ours is mocked: the camera is pypylon's runtime with
``PYLON_CAMEMU`` emulated devices, the motors are the production drivers
talking to the pty simulators, and the emulator serves as frames the
photographs a virtual-camera capture of the same plan wrote, so a capture
through the real driver must give the same CaptureSet.  Faults are made in
the emulator: the device destroyed mid-capture (unplugged), a forced failed
buffer (a frame lost in transport), an exposure past its range, a white frame.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("PYLON_CAMEMU", "2")  # before pypylon's transport layer factory first looks
pytest.importorskip("pypylon.pylon")

from sbrdf_capture.gonio import GonioCaptureError  # noqa: E402
from sbrdf_core.runner import run_graph  # noqa: E402
from sbrdf_core.testing import CameraTests  # noqa: E402
from sbrdf_devices.motors.sim import SimulatedIndexer, SimulatedPTU  # noqa: E402
from sbrdf_lib.camera import CameraLost, ExposureRefused, FrameTimeout  # noqa: E402
from sbrdf_lib.capture_folder import load_manifest, read_journal  # noqa: E402

from .test_gonio import ANGLES, capture_arrays, motors  # noqa: E402

W, H = 48, 36
TIMES = [0.0025, 0.01]
#: Linear 16-bit codes (gamma 1), so the emulator can serve them as RGB16Packed frames unchanged.
VIRTUAL = {"device": "virtual-camera",
           "params": {"width": W, "height": H, "focal_px": 180.0, "texels": [12, 12], "intensity": 4000000.0,
                      "sensitivity": 100.0, "effects": ["falloff", "saturation", "response", "noise"],
                      "response_curve": "gamma", "response_gamma": 1.0, "bit_depth": 16, "seed": 7}}


class TestPylonConformance(CameraTests):
    name = "pylon"
    params = {"pixel_format": "Mono12", "width": 64, "height": 48}


def graph(tmp_path: Path, name: str, n_poses: int = 6, **params) -> tuple[Path, Path, Path]:
    store, folder = tmp_path / f"{name}-store", tmp_path / f"{name}-scan"
    p = {"path": str(folder), "motors": motors(), "plan": {"angles_deg": ANGLES[:n_poses]},
         "exposures": {"times_s": TIMES}, "durable": False, **params}
    g = tmp_path / f"{name}.yaml"
    g.write_text(json.dumps({"name": name, "store": str(store),
                             "nodes": {"capture": {"kind": "Capture", "plugin": "gonio", "params": p}}}))
    return g, store, folder


@pytest.fixture(scope="module")
def virtual(tmp_path_factory):
    """The virtual camera's capture of the plan: its folder's frames are what the emulator serves."""
    tmp = tmp_path_factory.mktemp("virtual")
    g, store, folder = graph(tmp, "virtual", camera=VIRTUAL)
    run_graph(str(g))
    return store, folder


def pylon_params(virtual_folder: Path, **camera) -> dict:
    """gonio parameters for the pylon emulator serving the virtual capture's frames."""
    m = json.loads((virtual_folder / "capture.json").read_text())
    cam = {"device": "pylon", "params": {"pixel_format": "RGB16Packed", "width": W, "height": H,
                                         "emulation_frames": str(virtual_folder / "images" / "p{pose:05d}_e{exposure}.png"),
                                         **camera}}
    return {"camera": cam, "sample": m["sample"], "light": m["light"],
            "intrinsics": {"K": m["camera"]["K"], "dist": m["camera"]["dist"]}}


def test_pylon_capture_through_the_rig_equals_the_virtual_one(tmp_path, virtual):
    v_store, v_folder = virtual
    g, store, folder = graph(tmp_path, "pylon", **pylon_params(v_folder))
    run_graph(str(g))
    m = load_manifest(folder)
    assert m.complete and len(m.poses) == 6
    device = m.camera.extra["device"]
    assert (device["vendor"], device["model"], device["serial"]) == ("Basler", "Emulation", "0815-0000")
    assert device["pixel_format"] == "RGB16Packed" and device["white_balance"] == "off" and device["linear"]
    assert m.camera.response == "linear"
    for pose in m.poses:
        assert pose.extra["frames"]["requested_s"] == TIMES
        assert [e.time_s for e in pose.exposures] == pytest.approx(TIMES, rel=1e-3)  # the camera's own steps
    A, B = capture_arrays(v_store), capture_arrays(store)
    np.testing.assert_array_equal(A["valid"], B["valid"])
    np.testing.assert_allclose(A["images"], B["images"], rtol=1e-3, atol=1e-6)
    assert 0.05 < B["valid"].mean() < 0.95


def test_camera_unplugged_at_pose_k_stops_clearly_and_the_rerun_resumes_at_k(tmp_path, virtual, registry):
    v_store, v_folder = virtual
    g, store, folder = graph(tmp_path, "unplug", **pylon_params(v_folder))
    params = json.loads(g.read_text())["nodes"]["capture"]["params"]
    src = registry.create("capture", "gonio", params)
    src.bind(registry)
    src.describe()
    k = 3
    src.read_pose(k - 1)  # poses 0 .. k-1 taken
    src.camera._cam.DestroyDevice()  # the emulated device goes away, as an unplugged camera does
    with pytest.raises(GonioCaptureError) as err:
        src.read_pose(k)
    e = err.value
    assert isinstance(e.cause, CameraLost) and e.pose == k and e.motor == "camera"
    assert "disappeared" in str(e) and f"resume from pose {k}" in str(e) and "0815-0000" in str(e)
    assert sorted(r.id for r in read_journal(folder)) == list(range(k))
    src.close()

    run_graph(str(g))  # the same graph again: poses k.. are taken, 0..k-1 kept
    m = load_manifest(folder)
    assert m.complete and [p.id for p in m.poses] == list(range(6))
    np.testing.assert_allclose(capture_arrays(store)["images"], capture_arrays(v_store)["images"], rtol=1e-3, atol=1e-6)


@pytest.mark.parametrize("retries", [1, 0])
def test_a_lost_frame_is_retriggered_once_then_stops_the_capture(tmp_path, virtual, registry, retries):
    _, v_folder = virtual
    g, _, folder = graph(tmp_path, f"lost{retries}", n_poses=2, frame_retries=retries,
                         **pylon_params(v_folder, emulation_frames=None))  # a restart would clear the fault
    src = registry.create("capture", "gonio", json.loads(g.read_text())["nodes"]["capture"]["params"])
    src.bind(registry)
    src.describe()
    cam = src.camera._cam
    cam.ForceFailedBufferCount.Value = 1
    cam.ForceFailedBuffer.Execute()  # the emulator's next buffer arrives incomplete
    if retries:
        src.read_pose(0)
        assert [r.id for r in read_journal(folder)] == [0]
    else:
        with pytest.raises(GonioCaptureError) as err:
            src.read_pose(0)
        assert isinstance(err.value.cause, FrameTimeout) and "incomplete" in str(err.value)
        assert not read_journal(folder)
    src.close()


def test_an_exposure_the_camera_refuses_stops_the_plan_before_any_motion(tmp_path, virtual, start_simulator):
    _, v_folder = virtual
    sims = {"pan": start_simulator(SimulatedPTU), "tilt_roll": start_simulator(SimulatedPTU),
            "light": start_simulator(SimulatedIndexer)}
    g, _, folder = graph(tmp_path, "refused", **pylon_params(v_folder),
                         exposures={"times_s": [[0.01]] * 5 + [[0.01, 30.0]]})
    params = json.loads(g.read_text())
    params["nodes"]["capture"]["params"]["motors"] = motors(sims["pan"].port, sims["tilt_roll"].port,
                                                            sims["light"].port)
    g.write_text(json.dumps(params))
    before = (sims["pan"].position_deg("pan"), sims["tilt_roll"].position_deg("tilt"), sims["light"].position_deg(1))
    with pytest.raises(GonioCaptureError) as err:
        run_graph(str(g))
    e = err.value
    assert isinstance(e.cause, ExposureRefused) and e.pose == 5 and "before any motion" in str(e)
    assert "30 s" in str(e) and "[1e-06, 10] s" in str(e)
    assert (sims["pan"].position_deg("pan"), sims["tilt_roll"].position_deg("tilt"),
            sims["light"].position_deg(1)) == before
    assert not (folder / "images").exists() or not os.listdir(folder / "images")


def test_a_saturated_frame_is_masked_and_recorded_or_stops_the_capture(tmp_path, virtual, registry):
    import cv2

    _, v_folder = virtual
    white = tmp_path / "white.png"
    cv2.imwrite(str(white), np.full((H, W, 3), 65535, np.uint16))
    base = pylon_params(v_folder, emulation_frames=str(white))
    g, _, folder = graph(tmp_path, "white", n_poses=1, **base)
    src = registry.create("capture", "gonio", json.loads(g.read_text())["nodes"]["capture"]["params"])
    src.bind(registry)
    image, valid = src.read_pose(0)
    assert not valid.any()  # every pixel saturated in every exposure: nothing is a measurement
    assert load_manifest(folder).poses[0].extra["frames"]["saturated"] == [1.0, 1.0]

    g, _, folder = graph(tmp_path, "white-stop", n_poses=1, max_saturated_fraction=0.5, **base)
    src = registry.create("capture", "gonio", json.loads(g.read_text())["nodes"]["capture"]["params"])
    src.bind(registry)
    with pytest.raises(GonioCaptureError) as err:
        src.read_pose(0)
    assert "100.0% of the pixels" in str(err.value) and "max_saturated_fraction" in str(err.value)
    assert not read_journal(folder)
    src.close()


def test_a_frame_camera_without_sample_and_intrinsics_is_refused_at_bind(tmp_path, registry):
    from sbrdf_core.errors import ParameterError

    g, _, _ = graph(tmp_path, "bare", camera={"device": "pylon", "params": {}})
    src = registry.create("capture", "gonio", json.loads(g.read_text())["nodes"]["capture"]["params"])
    with pytest.raises(ParameterError, match="sample and intrinsics"):
        src.bind(registry)
