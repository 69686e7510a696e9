"""A scan through the real ``pylon`` driver, registered and fitted, gives the virtual camera's fit.

The whole pipeline a lab runs, as one graph per camera: ``gonio`` (the motor
drivers on the pty simulators) -> ``aruco`` -> ``Reflectance`` -> ``lm``
(1-lobe Lafortune).  Once with the virtual camera photographing a procedural
Lafortune SBRDF; once with pypylon's emulated Basler camera (``PYLON_CAMEMU``)
serving that capture's photographs as its frames, so the frames pass through
the driver's pixel format, MSB alignment, exposure steps, the folder writer
and the reader exactly as a real camera's would.

"Equal within the noise": a second virtual capture with another noise seed
gives the scatter that sensor noise alone puts into the fitted parameters,
``σ = 1.4826 · MAD(fit(seed 7) - fit(seed 8)) / √2`` per parameter; the
driver's fit must differ from the virtual camera's by far less than that
(95th percentile under ``DRIVER_SHARE · σ``).  The fast variant, on a smaller
scan, checks the driver's fit against the virtual one's to the camera's
exposure steps alone.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("PYLON_CAMEMU", "2")  # before pypylon's transport layer factory first looks
pytest.importorskip("pypylon.pylon")

from sbrdf_core.runner import run_graph  # noqa: E402
from sbrdf_core.store import open_artifact  # noqa: E402

from .test_gonio import motors  # noqa: E402

#: A driver's fit may differ from the virtual camera's by at most this share of the noise scatter σ.
DRIVER_SHARE = 0.1
#: Exposure bracket, s: inside the emulator's exposure range, on its 1 µs steps.
TIMES = [0.0025, 0.01]
#: Rig: camera 400 mm and light 500 mm from the sample, inside the PTU-46 and light-arm ranges.
GEOMETRY = {"camera_distance_mm": 400.0, "light_distance_mm": 500.0, "pan_limits_deg": [-159, 159],
            "tilt_limits_deg": [-47, 31], "roll_limits_deg": [-159, 159], "light_limits_deg": [10, 175]}


def virtual_camera(seed: int, texels: int, width: int, height: int, focal_px: float) -> dict:
    """Linear 16-bit photographs (gamma 1), so the emulator serves them as RGB16Packed frames unchanged."""
    return {"camera": {"device": "virtual-camera",
            "params": {"width": width, "height": height, "focal_px": focal_px, "texels": [texels, texels],
                       "model": "lafortune", "model_params": {"lobes": 1}, "intensity": 4000000.0,
                       "sensitivity": 25.0, "effects": ["falloff", "noise", "saturation", "response"],
                       "response_curve": "gamma", "response_gamma": 1.0, "bit_depth": 16, "seed": seed}}}


def pylon_camera(virtual_folder: Path, width: int, height: int) -> dict:
    """gonio parameters for the pylon emulator serving a virtual capture's photographs as frames."""
    m = json.loads((virtual_folder / "capture.json").read_text())
    cam = {"device": "pylon", "params": {"pixel_format": "RGB16Packed", "width": width, "height": height,
                                         "emulation_frames": str(virtual_folder / "images" / "p{pose:05d}_e{exposure}.png")}}
    return {"camera": cam, "sample": m["sample"], "light": m["light"],
            "intrinsics": {"K": m["camera"]["K"], "dist": m["camera"]["dist"]}}


def scan_and_fit(tmp_path: Path, name: str, theta_d_deg: float, texels: int, camera: dict) -> tuple[Path, Path]:
    """Capture -> register -> reflectance -> fit as one graph; returns (store, capture folder)."""
    store, folder = tmp_path / f"{name}-store", tmp_path / f"{name}-scan"
    capture = {"path": str(folder), "motors": motors(), "geometry": GEOMETRY,
               "plan": {"theta_d_deg": theta_d_deg, "isotropic": False, "max_theta_i_deg": 60.0,
                        "max_theta_r_deg": 50.0},
               "exposures": {"times_s": TIMES}, "durable": False, **camera}
    nodes = {"capture": {"kind": "Capture", "plugin": "gonio", "params": capture},
             "register": {"kind": "Register", "plugin": "aruco", "in": {"capture": "capture"},
                          "params": {"texels": [texels, texels]}},
             "reflectance": {"kind": "Reflectance", "in": {"stack": "register"}},
             "fit": {"kind": "Fit", "plugin": "lm", "in": {"samples": "reflectance"},
                     "params": {"model": "lafortune", "model_params": {"lobes": 1}}}}
    g = tmp_path / f"{name}.yaml"
    g.write_text(json.dumps({"name": name, "store": str(store), "nodes": nodes}))
    run_graph(str(g))
    return store, folder


def fitted(store: Path) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The fit's parameter maps ``{name: (V, U, C)}`` and the texels fitted from enough samples."""
    fit = open_artifact(str(store / "fit"))
    names = sorted(fit.group["params"].keys())
    maps = {k: np.asarray(fit.read(f"params/{k}"), np.float64).reshape(*fit.read("samples").shape, -1) for k in names}
    return maps, fit.read("samples") >= 9  # a 1-lobe Lafortune has 9 parameters per texel (RGB)


def compare(a: dict, b: dict, ok: np.ndarray) -> dict[str, np.ndarray]:
    """Per parameter, the texel differences where both fits have enough samples."""
    return {k: (a[k] - b[k])[ok] for k in a}


def noise_sigma(d: np.ndarray) -> float:
    """The parameter scatter one capture's noise causes, from the difference of two captures' fits."""
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def test_pylon_scan_registered_and_fitted_equals_the_virtual_cameras_fast(tmp_path):
    """19 poses, 8² texels: the driver's fit is the virtual camera's to within its exposure steps."""
    size = {"width": 240, "height": 180, "focal_px": 360.0}
    v_store, v_folder = scan_and_fit(tmp_path, "virtual", 40.0, 8, virtual_camera(7, 8, **size))
    p_store, _ = scan_and_fit(tmp_path, "pylon", 40.0, 8, pylon_camera(v_folder, size["width"], size["height"]))
    (v, v_ok), (p, p_ok) = fitted(v_store), fitted(p_store)
    np.testing.assert_array_equal(v_ok, p_ok)
    assert v_ok.mean() > 0.8
    for k, d in compare(v, p, v_ok).items():
        scale = np.abs(v[k][v_ok]).max() + 1e-12
        assert np.percentile(np.abs(d), 95) < 1e-3 * scale, (k, np.percentile(np.abs(d), 95), scale)


@pytest.mark.slow
def test_pylon_scan_registered_and_fitted_equals_the_virtual_cameras_within_the_noise(tmp_path):
    """30 poses, 16² texels; the tolerance is DRIVER_SHARE of the scatter sensor noise causes (module docstring)."""
    size = {"width": 320, "height": 240, "focal_px": 480.0}
    v_store, v_folder = scan_and_fit(tmp_path, "virtual", 35.0, 16, virtual_camera(7, 16, **size))
    n_store, _ = scan_and_fit(tmp_path, "virtual-seed8", 35.0, 16, virtual_camera(8, 16, **size))
    p_store, _ = scan_and_fit(tmp_path, "pylon", 35.0, 16, pylon_camera(v_folder, size["width"], size["height"]))
    (v, v_ok), (n, n_ok), (p, p_ok) = fitted(v_store), fitted(n_store), fitted(p_store)
    ok = v_ok & n_ok & p_ok
    assert ok.mean() > 0.8
    noise = compare(v, n, ok)
    driver = compare(v, p, ok)
    report = []
    for k in v:
        sigma = noise_sigma(noise[k])
        p95 = float(np.percentile(np.abs(driver[k]), 95))
        report.append(f"{k}: noise sigma {sigma:.3g}, driver p95 {p95:.3g}")
        if not np.ptp(v[k][ok]) and not np.ptp(n[k][ok]):
            assert p95 == 0, k  # a parameter the model form holds (a Lafortune lobe's c_z): nothing to scatter
            continue
        assert sigma > 0, k  # the two virtual captures' noise differs, so their fits do
        assert p95 <= DRIVER_SHARE * sigma, (k, sigma, p95)
    print("\n" + "\n".join(report))
