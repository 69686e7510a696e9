"""Dark frames and flat fields as nodes: what the virtual camera adds is taken out again.

The virtual camera is given a black-level pedestal, dark current and strong
vignetting (a wide lens: the corners get ~0.6 of the centre's light); the
``DarkFrame`` and ``FlatField`` nodes measure them with that camera, and the
Capture node's ``dark`` and ``flat`` inputs correct every exposure.  The
reference is the same capture by the same camera without those effects.
The same nodes drive pypylon's emulated Basler camera serving the virtual
camera's dark frames as files.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact
from sbrdf_lib.calibration import correct, fit_dark, flat_usable, normalise_flat

#: A wide lens (corner angle ~30 deg) on linear 16-bit codes; the reference camera lacks the three effects.
BASE = {"width": 200, "height": 150, "focal_px": 220.0, "texels": [16, 16], "intensity": 250000.0,
        "sensitivity": 1.0, "response_curve": "gamma", "response_gamma": 1.0, "bit_depth": 16, "seed": 7}
EFFECTS = ["falloff", "noise", "saturation", "response"]
CALIBRATED = ["vignetting", "dark_current", "black_level"]
CAMERA = {"device": "virtual-camera", "params": {**BASE, "effects": EFFECTS + CALIBRATED, "black_level": 0.03,
                                                 "dark_current": 0.02}}
IDEAL = {"device": "virtual-camera", "params": {**BASE, "effects": EFFECTS}}
TIMES = [0.25, 1.0]


def graph(tmp_path: Path, name: str, camera: dict, calibrate: bool, poses: int = 4) -> Path:
    nodes: dict = {}
    capture = {"kind": "Capture", "plugin": "virtual-folder",
               "params": {"path": str(tmp_path / f"{name}-scan"), "camera": camera, "poses": poses,
                          "exposures": TIMES, "durable": False}}
    if calibrate:
        nodes["dark"] = {"kind": "DarkFrame", "params": {"camera": camera, "times_s": TIMES, "frames": 8}}
        nodes["flat"] = {"kind": "FlatField", "in": {"dark": "dark"},
                         "params": {"camera": camera, "time_s": 0.5, "frames": 8}}
        capture["in"] = {"dark": "dark", "flat": "flat"}
    nodes["capture"] = capture
    g = tmp_path / f"{name}.yaml"
    g.write_text(json.dumps({"name": name, "store": str(tmp_path / f"{name}-store"), "nodes": nodes}))
    return g


def images(tmp_path: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    cap = open_artifact(str(tmp_path / f"{name}-store" / "capture"))
    return cap.read("images"), cap.read("valid")


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("calibration")
    for name, camera, calibrate in (("calibrated", CAMERA, True), ("raw", CAMERA, False), ("ideal", IDEAL, False)):
        run_graph(str(graph(tmp, name, camera, calibrate)))
    return tmp


def test01_dark_model_and_flat_pass_the_worked_example():
    times = [0.1, 1.0, 2.0]
    offset = np.array([[[0.01, 0.02, 0.03]]], np.float32)
    rate = np.array([[[0.002, 0.0, 0.004]]], np.float32)
    o, r = fit_dark(times, [offset + rate * t for t in times])
    np.testing.assert_allclose(o, offset, atol=1e-7)
    np.testing.assert_allclose(r, rate, atol=1e-7)
    o1, r1 = fit_dark([0.5], [offset + rate * 0.5])  # one time: its dark signal is a pedestal
    np.testing.assert_allclose(o1, offset + rate * 0.5, atol=1e-7)
    assert not r1.any()
    flat = normalise_flat(np.array([[[0.0] * 3, [0.4] * 3, [0.2] * 3]], np.float32), centre_fraction=0.3)
    np.testing.assert_allclose(flat[0, :, 0], [0.0, 1.0, 0.5])
    assert flat_usable(flat).tolist() == [[False, True, True]]
    np.testing.assert_allclose(correct(np.full((1, 3, 3), 0.3, np.float32), 1.0, flat=flat)[0, :, 0], [0.3, 0.3, 0.6])


def test02_the_nodes_measure_what_the_camera_adds(captures, registry):
    cam = registry.create("device", "virtual-camera", CAMERA["params"])
    dark = open_artifact(str(captures / "calibrated-store" / "dark"))
    flat = open_artifact(str(captures / "calibrated-store" / "flat"))
    assert dark.attrs["model"] == "offset+rate" and dark.attrs["times_s"] == TIMES
    # 8 frames of read noise 0.001 and shot noise of the dark signal: the mean is good to ~5e-4 per sensel.
    assert np.abs(dark.read("offset") - cam._black_level()).mean() < 5e-4
    assert np.abs(dark.read("rate") - cam._dark_rate()).mean() < 1e-3
    truth = cam.vignetting()[..., None]
    f = flat.read("flat")
    assert flat.attrs["dark_corrected"] and f.shape == (150, 200, 3)
    np.testing.assert_allclose(np.median(np.abs(f - truth / truth.max())), 0.0, atol=3e-3)
    assert flat.attrs["corner_mean"][0] < 0.7  # the vignetting the flat is to remove is strong


def test03_calibrated_capture_equals_the_camera_without_vignetting_and_dark_signal(captures):
    a, va = images(captures, "calibrated")
    b, vb = images(captures, "raw")
    c, vc = images(captures, "ideal")
    ok = va & vb & vc
    assert ok.sum() > 0.9 * vc.sum() and vc.mean() > 0.15  # the lit carrier and sample; the wide view sees more
    lum = lambda x: x[ok].mean(axis=-1)  # noqa: E731
    rel_cal = np.abs(lum(a) / lum(c) - 1)
    rel_raw = np.abs(lum(b) / lum(c) - 1)
    print(f"\nmedian relative error vs the ideal camera: calibrated {np.median(rel_cal):.4f}, raw {np.median(rel_raw):.4f}")
    assert np.median(rel_cal) < 0.01 and np.median(rel_raw) > 0.1
    # The pedestal shows in the dark parts (the black ArUco markers): biased raw, unbiased calibrated.
    dark = lum(c) < np.percentile(lum(c), 10)
    full = 1.0 / min(TIMES)  # the radiance of full scale in the shortest exposure
    bias_cal, bias_raw = (lum(a) - lum(c))[dark].mean() / full, (lum(b) - lum(c))[dark].mean() / full
    print(f"dark-pixel bias (share of full scale): calibrated {bias_cal:.2e}, raw {bias_raw:.2e}")
    assert abs(bias_cal) < 1e-3 < bias_raw


def test04_a_source_without_calibrate_refuses_the_inputs(tmp_path):
    nodes = {"dark": {"kind": "DarkFrame", "params": {"camera": IDEAL, "times_s": [1.0], "frames": 1}},
             "capture": {"kind": "Capture", "plugin": "synthetic", "in": {"dark": "dark"},
                         "params": {"texels": [4, 4], "poses": 2}}}
    g = tmp_path / "g.yaml"
    g.write_text(json.dumps({"name": "g", "store": str(tmp_path / "store"), "nodes": nodes}))
    with pytest.raises(SbrdfError, match="cannot apply calibration"):
        run_graph(str(g))


def test05_an_uncapped_lens_is_refused(tmp_path):
    lit = {"device": "virtual-camera", "params": {**BASE, "effects": EFFECTS + ["black_level"], "black_level": 0.4}}
    nodes = {"dark": {"kind": "DarkFrame", "params": {"camera": lit, "times_s": [1.0], "frames": 1}}}
    g = tmp_path / "g.yaml"
    g.write_text(json.dumps({"name": "g", "store": str(tmp_path / "store"), "nodes": nodes}))
    with pytest.raises(SbrdfError, match="cap the lens"):
        run_graph(str(g))


def test06_dark_frames_through_the_pylon_emulator(tmp_path, registry):
    """The DarkFrame node on a real driver: pypylon's emulator serves the virtual camera's dark frames."""
    os.environ.setdefault("PYLON_CAMEMU", "2")
    pytest.importorskip("pypylon.pylon")
    import cv2

    cam = registry.create("device", "virtual-camera", CAMERA["params"])
    for k, t in enumerate(TIMES):
        for i in range(4):
            cv2.imwrite(str(tmp_path / f"d{i}_{k}.png"), cam.dark_frame(t, frame_id=i)[..., ::-1])
    pylon = {"device": "pylon", "params": {"pixel_format": "RGB16Packed", "width": BASE["width"],
                                           "height": BASE["height"],
                                           "emulation_frames": str(tmp_path / "d{pose}_{exposure}.png")}}
    virtual = dict(CAMERA)
    nodes = {"pylon": {"kind": "DarkFrame", "params": {"camera": pylon, "times_s": TIMES, "frames": 4}},
             "virtual": {"kind": "DarkFrame", "params": {"camera": virtual, "times_s": TIMES, "frames": 4}}}
    g = tmp_path / "g.yaml"
    g.write_text(json.dumps({"name": "g", "store": str(tmp_path / "store"), "nodes": nodes}))
    run_graph(str(g))
    p, v = open_artifact(str(tmp_path / "store" / "pylon")), open_artifact(str(tmp_path / "store" / "virtual"))
    assert p.attrs["camera"]["driver"] == "pylon" and p.attrs["camera"]["model"] == "Emulation"
    np.testing.assert_allclose(p.read("offset"), v.read("offset"), atol=1e-6)
    np.testing.assert_allclose(p.read("rate"), v.read("rate"), atol=1e-5)
