"""The virtual camera: geometry against cv2 (ArUco detection, projection), and every effect on and off."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core.errors import ParameterError, PluginError
from sbrdf_core.geometry import look_at
from sbrdf_devices.cameras.virtual import EFFECTS

SMALL = {"width": 160, "height": 120, "focal_px": 200.0, "texels": [16, 16]}
OVERHEAD = (np.array([0.0, 0.0, 300.0]),) + look_at(np.array([0.0, 0.0, 400.0]))


def camera(registry, **params):
    cam = registry.create("device", "virtual-camera", {**SMALL, **params})
    cam.bind(registry)
    return cam


def flat(registry, **params):
    """A huge uniform Lambertian sample filling the view, no distortion: radiance is analytic."""
    return camera(registry, texels=[1, 1], sample_size_mm=[5000.0, 5000.0], dist=[0, 0, 0, 0, 0], **params)


def test_markers_are_detected_where_projected(registry):
    cam = camera(registry, width=640, height=480, focal_px=900.0, effects=["falloff"])
    R, t = look_at(np.array([40.0, -120.0, 330.0]))
    img = cam.photograph([80, 40, 400], R, t, 2.0)
    gray = cv2.cvtColor(np.clip(img * 255 / img.max(), 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = det.detectMarkers(gray)
    assert ids is not None and sorted(ids.ravel()) == list(range(12))
    obj = np.asarray(cam.sample_info()["fiducials"]["markers"][0]["corners_mm"])
    assert obj.shape == (4, 2)
    for c, i in zip(corners, ids.ravel()):
        pts = np.concatenate([cam.marker_corners_mm()[i], np.zeros((4, 1))], axis=1)
        proj, _ = cv2.projectPoints(pts, cv2.Rodrigues(R)[0], t, cam.K, cam.dist)
        assert np.abs(proj.reshape(4, 2) - c.reshape(4, 2)).max() < 2.5, f"marker {i}"


@settings(max_examples=20, deadline=None)
@given(k1=st.floats(-0.3, 0.3), k2=st.floats(-0.1, 0.1), p1=st.floats(-0.01, 0.01))
def test_pixel_rays_reproject_through_the_distortion_model(k1, k2, p1, registry):
    cam = camera(registry, width=64, height=48, focal_px=80.0, dist=[k1, k2, p1, 0.0, 0.0])
    rays = np.ascontiguousarray(cam.rays().reshape(-1, 3))
    proj, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    v, u = np.divmod(np.arange(64 * 48), 64)
    assert np.abs(proj.reshape(-1, 2) - np.stack([u, v], axis=1)).max() < 1e-3


def test_no_effects_is_linear_float_and_runs_nothing(registry):
    cam = camera(registry, effects=[])
    img = cam.photograph(*OVERHEAD, 1.0)
    assert img.dtype == np.float32 and cam.effects_ran == set()
    assert cam.camera_info()["response"] == "linear"
    np.testing.assert_allclose(cam.photograph(*OVERHEAD, 2.0), 2 * img, rtol=1e-6)


def test_all_effects_run_and_are_recorded(registry):
    # shadowing and masking act on a height field: give the sample one (sbrdf_lib.mesostructure)
    cam = camera(registry, effects=list(EFFECTS), mesostructure={"height_mm": {"procedural": "bumps", "amplitude_mm": 1.0}})
    img = cam.photograph(*OVERHEAD, 1.0, pose_id=0)
    assert img.dtype == np.uint8 and cam.effects_ran == set(EFFECTS)
    assert cam.simulation_info()["effects"] == list(EFFECTS)


def test_unknown_effect_is_rejected(registry):
    with pytest.raises(ParameterError, match=r"unknown effect\(s\) \['glare'\]"):
        camera(registry, effects=["glare"])
    with pytest.raises(PluginError, match="bit_depth"):
        camera(registry, bit_depth=12)


def test_vignetting(registry):
    on = flat(registry, effects=["vignetting"]).photograph(*OVERHEAD, 1.0)
    off = flat(registry, effects=[]).photograph(*OVERHEAD, 1.0)
    H, W = off.shape[:2]
    cam = flat(registry)
    ray = np.array([(0 - cam.K[0, 2]) / cam.K[0, 0], (0 - cam.K[1, 2]) / cam.K[1, 1], 1.0])
    cos4 = (1 / np.linalg.norm(ray)) ** 4
    centre = off[H // 2, W // 2, 0]
    assert off[0, 0, 0] == pytest.approx(centre, rel=1e-6)  # off: centre/corner ratio 1
    # (the centre pixel is half a pixel off-axis: compare against its own cos^4)
    assert on[0, 0, 0] / on[H // 2, W // 2, 0] == pytest.approx(cos4 / (1 / np.linalg.norm(cam.rays()[H // 2, W // 2])) ** 4, rel=1e-5)


def test_falloff(registry):
    cam_on = flat(registry, effects=["falloff"])
    on = cam_on.photograph(*OVERHEAD, 1.0)
    off = flat(registry, effects=[]).photograph(*OVERHEAD, 1.0)
    assert np.ptp(off, axis=(0, 1)).max() == pytest.approx(0.0, abs=1e-7)
    # on: E = I z / r^3 at the point each pixel sees; corner pixel vs the analytic value
    R, t = OVERHEAD[1], OVERHEAD[2]
    d = cam_on.rays()[0, 0] @ R
    c = -R.T @ t
    X = c - c[2] / d[2] * d
    r = np.linalg.norm(OVERHEAD[0] - X)
    rho = cam_on.ground_truth()["rho_d"][0, 0, 0]
    assert on[0, 0, 0] == pytest.approx(rho * cam_on.intensity * OVERHEAD[0][2] / r**3, rel=1e-5)
    assert on[0, 0, 0] < off[0, 0, 0]


def test_saturation(registry):
    on = flat(registry, effects=["saturation"], intensity=1e7).photograph(*OVERHEAD, 1.0)
    off = flat(registry, effects=[], intensity=1e7).photograph(*OVERHEAD, 1.0)
    assert off.max() > 1 and on.max() == 1.0
    assert flat(registry, effects=["saturation"]).camera_info()["white_level"] == 1.0


@pytest.mark.parametrize("curve,bits", [("srgb", 8), ("gamma", 16), ("cubic", 8)])
def test_response(curve, bits, registry):
    cam = flat(registry, effects=["response", "falloff"], response_curve=curve, bit_depth=bits)
    img = cam.photograph(*OVERHEAD, 1.0)
    assert img.dtype == (np.uint8 if bits == 8 else np.uint16)
    S = flat(registry, effects=["falloff"]).photograph(*OVERHEAD, 1.0)
    back = cam.curve().linearize(img)
    step = np.abs(np.gradient(cam.curve().table[:, 0])).max()
    assert np.abs(back - S).max() <= step  # within one code of the true signal
    assert cam.camera_info()["response"]["type"] == "table"
    assert "response" not in camera(registry, effects=["response"], record_response=False).camera_info()


def test_noise_is_seeded_per_pose_and_exposure(registry):
    cam = flat(registry, effects=["noise"], read_noise=0.01, full_well=1000.0)
    clean = flat(registry, effects=[]).photograph(*OVERHEAD, 1.0)
    a = cam.photograph(*OVERHEAD, 1.0, pose_id=5)
    assert np.array_equal(a, cam.photograph(*OVERHEAD, 1.0, pose_id=5))
    assert not np.array_equal(a, cam.photograph(*OVERHEAD, 1.0, pose_id=6))
    assert not np.array_equal(a, cam.photograph(*OVERHEAD, 1.0, pose_id=5, exposure_index=1))
    expected = np.sqrt(clean / 1000.0 + 0.01**2)
    z = (a - clean) / expected
    assert abs(z.mean()) < 0.05 and z.std() == pytest.approx(1.0, abs=0.05)
    assert np.array_equal(flat(registry, effects=[]).photograph(*OVERHEAD, 1.0, pose_id=6), clean)  # off: no noise


def test_dark_current_and_dark_frame(registry):
    cam = flat(registry, effects=["dark_current"], dark_current=0.01)
    dark = cam.dark_frame(2.0)
    assert dark.mean() == pytest.approx(0.02, rel=0.02) and dark.min() >= 0
    np.testing.assert_allclose(cam.dark_frame(4.0), 2 * dark, rtol=1e-6)  # a fixed pattern, ∝ time
    assert not flat(registry, effects=[]).dark_frame(2.0).any()
    lit = cam.photograph(*OVERHEAD, 2.0)
    clean = flat(registry, effects=[]).photograph(*OVERHEAD, 2.0)
    np.testing.assert_allclose(lit - dark, clean, atol=1e-6)


def test_motor_error(registry):
    cam = camera(registry, effects=["motor_error"], motor_rotation_deg=1.0, motor_light_mm=3.0)
    light, R, t = OVERHEAD
    tl, tR, tt = cam.true_pose(light, R, t, pose_id=2)
    angle = np.degrees(np.arccos(np.clip((np.trace(R.T @ tR) - 1) / 2, -1, 1)))
    assert 0 < angle < 5 and 0 < np.linalg.norm(tl - light) < 30
    assert np.array_equal(cam.true_pose(light, R, t, pose_id=2)[1], tR)  # one true pose per pose id
    assert not np.array_equal(cam.true_pose(light, R, t, pose_id=3)[1], tR)
    assert cam.true_poses[2][1] is not None
    nominal = camera(registry, effects=[])
    assert all(np.array_equal(a, b) for a, b in zip(nominal.true_pose(light, R, t, 2), (light, R, t)))
    assert not np.array_equal(cam.photograph(light, R, t, 1.0, pose_id=2), nominal.photograph(light, R, t, 1.0))


def test_blur(registry):
    on = camera(registry, effects=["blur"], blur_px=1.5).photograph(*OVERHEAD, 1.0)
    off = camera(registry, effects=[]).photograph(*OVERHEAD, 1.0)
    np.testing.assert_allclose(on, cv2.GaussianBlur(off, (0, 0), 1.5, borderType=cv2.BORDER_REFLECT), atol=1e-6)
    assert np.abs(np.diff(on, axis=1)).mean() < np.abs(np.diff(off, axis=1)).mean()


def test_any_installed_model_and_texel_lookup(registry):
    cam = camera(registry, effects=[], sample_size_mm=[5000.0, 5000.0], texels=[2, 1], dist=[0, 0, 0, 0, 0])
    rho = cam.ground_truth()["rho_d"]
    img = cam.photograph(*OVERHEAD, 1.0)
    rc = np.linalg.norm(OVERHEAD[0])
    E = cam.intensity * OVERHEAD[0][2] / rc**3
    H, W = img.shape[:2]
    np.testing.assert_allclose(img[H // 2, 2], rho[0, 0] * E, rtol=1e-5)  # x < 0: texel u = 0
    np.testing.assert_allclose(img[H // 2, W - 3], rho[0, 1] * E, rtol=1e-5)
