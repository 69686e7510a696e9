"""Radiometric and colour calibration: response recovery, HDR merge, dark frames, colour matrix."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from sbrdf_capture.colour import (
    LINEAR_SRGB_TO_XYZ,
    XYZ_TO_LINEAR_SRGB,
    ColourError,
    apply_matrix,
    camera_to_working,
    colour_checker_xyz,
    fit_camera_to_xyz,
)
from sbrdf_capture.hdr import merge_exposures
from sbrdf_capture.photograph import capture_to_folder, orbit_poses
from sbrdf_capture.response import (
    ResponseCurve,
    codes,
    cubic_table,
    fit_cubic_loglog,
    gamma_table,
    relative_error,
    srgb_table,
)

CAM = {"width": 160, "height": 120, "focal_px": 210.0, "texels": [32, 32]}
BRACKET = [0.25, 1.0, 4.0]


def capture(registry, path, poses=4, exposures=BRACKET, **params):
    cam = registry.create("device", "virtual-camera", {**CAM, **params})
    cam.bind(registry)
    light, R, t = orbit_poses(poses)
    capture_to_folder(cam, path, light, R, t, [exposures] * poses, durable=False)
    return cam, (light, R, t)


@pytest.mark.parametrize("curve,bits,method,noise,tolerance", [
    ("srgb", 8, "cubic", False, 0.01), ("gamma", 16, "cubic", False, 0.005), ("cubic", 8, "cubic", False, 0.01),
    ("srgb", 8, "debevec", False, 0.05),
    ("srgb", 8, "cubic", True, 0.03), ("gamma", 16, "cubic", True, 0.06), ("srgb", 8, "debevec", True, 0.1),
])
def test_response_recovered_from_virtual_brackets(curve, bits, method, noise, tolerance, registry, tmp_path):
    effects = ["response", "falloff"] + (["noise"] if noise else [])
    cam, _ = capture(registry, tmp_path / "s", effects=effects, response_curve=curve, bit_depth=bits, record_response=False)
    src = registry.create("capture", "folder", {"path": str(tmp_path / "s"), "response_method": method})
    src.describe()
    truth = cam.curve().table[:, 0]
    # Debevec is defined up to scale; the cubic is anchored at saturation (g(max) = 1) and needs no rescale.
    err = relative_error(src.curve.table, truth, 0.1, 0.9, fit_scale=(method == "debevec"))
    print(f"\nresponse recovery {curve}/{bits}-bit/{method}/noise={noise}: max relative error over codes 10-90% = {err:.4f}")
    assert err < tolerance


def test_hdr_merge_matches_simulator_radiance(registry, tmp_path):
    cam, (light, R, t) = capture(registry, tmp_path / "s", effects=["response", "falloff", "saturation"],
                                 response_curve="srgb", bit_depth=16, intensity=2.5e6)
    src = registry.create("capture", "folder", {"path": str(tmp_path / "s")})
    src.describe()
    errs, saturated_single = [], 0
    for i in range(len(light)):
        image, valid = src.read_pose(i)
        truth = cam.sensor_radiance(light[i], R[i], t[i], i)
        # dynamic range: some pixels saturate in the longest exposure but are valid through the shorter ones
        saturated_single += int(((truth * BRACKET[-1]) >= 1).any(axis=-1)[valid].sum())
        rel = np.abs(image - truth)[valid] / truth[valid]
        errs.append(rel)
        assert not valid[truth.max(axis=-1) * BRACKET[0] >= 1].any()  # saturated in every exposure: invalid
    rel = np.concatenate(errs)
    print(f"\nHDR merge vs simulator radiance (16-bit sRGB, 3 exposures): median {np.median(rel):.2e}, max {rel.max():.2e}")
    assert saturated_single > 0
    assert rel.max() < 2e-3


def test_dark_frame_subtraction(registry, tmp_path):
    cam, (light, R, t) = capture(registry, tmp_path / "s", poses=2, exposures=[2.0],
                                 effects=["dark_current", "falloff"], dark_current=0.02)
    from sbrdf_lib.capture_folder import encode_image

    (tmp_path / "s" / "images" / "dark.exr").write_bytes(encode_image(cam.dark_frame(10.0), ".exr"))
    plain = registry.create("capture", "folder", {"path": str(tmp_path / "s")})
    fixed = registry.create("capture", "folder", {"path": str(tmp_path / "s"), "dark_frame": "images/dark.exr",
                                                  "dark_time_s": 10.0})
    plain.describe(), fixed.describe()
    truth = cam.sensor_radiance(light[1], R[1], t[1], 1)
    bias = np.abs(plain.read_pose(1)[0] - truth).mean()
    assert bias == pytest.approx(0.02, rel=0.05)  # dark current / time: 0.02 signal/s ÷ 1 s⁻¹ ... per unit radiance
    np.testing.assert_allclose(fixed.read_pose(1)[0], truth, atol=1e-5)


@settings(max_examples=30, deadline=None)
@given(a1=st.floats(1.5, 2.6), a2=st.floats(-0.08, 0.0), a3=st.floats(-0.01, 0.0), bits=st.sampled_from([8, 16]))
def test_cubic_fit_inverts_known_exposures(a1, a2, a3, bits):
    """McAllister's calibration: ND-filter/shutter data with known relative exposure -> the cubic."""
    y = np.log(codes(bits)[1:])
    assume(np.all(a1 + 2 * a2 * y + 3 * a3 * y**2 > 0.2))  # a monotone camera curve
    truth = cubic_table(bits, [a1, a2, a3])
    curve = ResponseCurve(truth)
    X = np.geomspace(1e-3, 0.95, 60)
    Z = curve.expose(np.repeat(X[:, None], 3, axis=1))[:, 0].astype(float)
    coef = fit_cubic_loglog(Z, X, curve.max_code)
    fitted = cubic_table(bits, coef)
    assert relative_error(fitted, truth, 0.1, 0.9) < (0.03 if bits == 8 else 0.002)


@settings(max_examples=30, deadline=None)
@given(signal=st.floats(0.03, 0.9), times=st.lists(st.floats(0.01, 1.0), min_size=1, max_size=3))
def test_merge_of_consistent_exposures_is_exact(signal, times):
    """Exposures of one radiance agree; merging them returns that radiance whatever the weights."""
    L = signal / max(times)
    sig = [np.full((2, 2, 3), L * tt, np.float32) for tt in times]
    lev = [s.copy() for s in sig]
    radiance, valid = merge_exposures(sig, lev, times, 0.98, 0.001)
    assert valid.all()
    np.testing.assert_allclose(radiance, L, rtol=1e-5)


def test_merge_marks_saturated_and_dark_invalid():
    sig = [np.array([[[1.0, 1.0, 1.0], [0.001, 0.5, 0.5]]], np.float32)]
    radiance, valid = merge_exposures(sig, sig, [0.5], 0.98, 0.02)
    assert valid.tolist() == [[False, False]]
    assert radiance[0, 0, 0] == pytest.approx(2.0)  # best guess kept, flagged invalid


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), noise=st.floats(0.0, 1e-3))
def test_colour_matrix_recovered_from_checker(seed, noise):
    rng = np.random.default_rng(seed)
    M = np.eye(3) + rng.uniform(-0.3, 0.3, (3, 3))  # camera -> XYZ
    xyz = colour_checker_xyz()
    camera_rgb = xyz @ np.linalg.inv(M).T
    camera_rgb = camera_rgb + noise * rng.standard_normal(camera_rgb.shape)
    fitted = fit_camera_to_xyz(camera_rgb, xyz)
    assert np.abs(fitted - M).max() < 1e-6 + 50 * noise
    working = apply_matrix(camera_rgb[None], camera_to_working(fitted))[0]
    expected = xyz @ XYZ_TO_LINEAR_SRGB.T
    assert np.abs(working - expected).max() < 1e-5 + 200 * noise


def test_colour_checker_and_working_space():
    xyz = colour_checker_xyz()
    white = xyz[18]
    assert white[1] == pytest.approx(0.9, abs=0.02)  # the white patch, Y ≈ 0.9
    np.testing.assert_allclose(XYZ_TO_LINEAR_SRGB @ LINEAR_SRGB_TO_XYZ, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(LINEAR_SRGB_TO_XYZ[:, :].sum(axis=1), [0.95047, 1.0, 1.08883], atol=1e-4)  # D65 white
    with pytest.raises(ColourError, match="rank < 3"):
        grey = np.repeat(np.linspace(0.1, 0.9, 6)[:, None], 3, axis=1)
        fit_camera_to_xyz(grey, grey)


def test_tables():
    assert gamma_table(8)[-1] == 1.0 and srgb_table(16)[-1] == pytest.approx(1.0)
    assert codes(8)[0] == 0 and np.all(np.diff(srgb_table(8)) > 0)
    curve = ResponseCurve(srgb_table(8))
    assert np.array_equal(curve.expose(curve.linearize(np.arange(256, dtype=np.uint8).reshape(1, -1, 1).repeat(3, -1))),
                          np.arange(256, dtype=np.uint8).reshape(1, -1, 1).repeat(3, -1))


@pytest.mark.parametrize("method,tolerance", [("debevec", 0.05), ("cubic", 0.02)])
def test_response_recovered_from_brackets_that_differ_per_pose(method, tolerance, registry, tmp_path):
    """Issue 23: the exposure planner gives each pose its own bracket (1-3 times, placed by the predicted
    dynamic range), so recovery must take samples with their own exposure times; Debevec used to refuse such a
    folder ("needs the same exposure times in every bracket")."""
    cam = registry.create("device", "virtual-camera", {**CAM, "effects": ["response", "falloff"],
                                                       "response_curve": "srgb", "bit_depth": 8,
                                                       "record_response": False})
    cam.bind(registry)
    light, R, t = orbit_poses(6)
    brackets = [[0.25, 1.0, 4.0], [0.5, 2.0], [0.1, 0.4, 1.6], [0.3, 1.5, 6.0], [0.8], [0.2, 0.7, 2.5]]
    capture_to_folder(cam, tmp_path / "s", light, R, t, brackets, durable=False)
    src = registry.create("capture", "folder", {"path": str(tmp_path / "s"), "response_method": method})
    src.describe()
    err = relative_error(src.curve.table, cam.curve().table[:, 0], 0.1, 0.9, fit_scale=(method == "debevec"))
    print(f"\nresponse recovery from per-pose brackets, srgb/8-bit/{method}: max relative error over codes 10-90% = "
          f"{err:.4f}")
    assert err < tolerance


def test_response_recovery_failure_says_what_was_tried(registry, tmp_path):
    """No pose has two exposures: the error says the response is absent and why it cannot be recovered."""
    from sbrdf_lib.capture_folder import CaptureFolderError

    capture(registry, tmp_path / "s", poses=2, exposures=[1.0], effects=["response"], response_curve="srgb",
            bit_depth=8, record_response=False)
    src = registry.create("capture", "folder", {"path": str(tmp_path / "s"), "response_method": "debevec"})
    with pytest.raises(CaptureFolderError, match="camera.response is absent and no pose has an exposure bracket"):
        src.describe()
