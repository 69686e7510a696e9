"""Rig kinematics: frames, offsets, and forward/inverse round trips (property-based)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_lib.rig_geometry import RigGeometry, forward, inverse

angles = st.tuples(st.floats(-60, 60), st.floats(-60, 60), st.floats(-170, 170), st.floats(15, 170))
offsets = st.builds(
    RigGeometry,
    camera_distance_mm=st.floats(600, 1500), light_distance_mm=st.floats(600, 1500),
    camera_height_mm=st.floats(-50, 50), light_height_mm=st.floats(-50, 50),
    tilt_axis_offset_mm=st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-20, 20)),
    sample_standoff_mm=st.floats(0, 40), sample_center_offset_mm=st.tuples(st.floats(-30, 30), st.floats(-30, 30)),
    pan_zero_deg=st.floats(-3, 3), tilt_zero_deg=st.floats(-3, 3), roll_zero_deg=st.floats(-3, 3),
    light_zero_deg=st.floats(-3, 3),
)


def test_zero_pose_faces_the_camera():
    g = RigGeometry(sample_standoff_mm=0.0)
    p = forward(g, 0, 0, 0, 90)
    np.testing.assert_allclose(p.camera_center_mm[0], [0, 0, 1084.0], atol=1e-9)
    np.testing.assert_allclose(p.light_pos_mm[0], [1000.0, 0, 0], atol=1e-9)  # arm at 90 deg: grazing along +u
    # OpenCV: the camera looks down -z of the sample, its x along the sample's u
    np.testing.assert_allclose(p.camera_R[0], [[1, 0, 0], [0, -1, 0], [0, 0, -1]], atol=1e-12)
    np.testing.assert_allclose(p.camera_t[0], [0, 0, 1084.0], atol=1e-9)
    wi, wo = p.directions()
    np.testing.assert_allclose(wo[0], [0, 0, 1], atol=1e-12)


def test_tilt_lifts_the_normal_and_roll_spins_about_it():
    g = RigGeometry(sample_standoff_mm=0.0)
    _, wo = forward(g, 0, 30, 0, 90).directions()
    assert np.degrees(np.arccos(wo[0, 2])) == pytest.approx(30.0)
    assert wo[0, 1] < 0  # the camera now sits "below" the sample's v axis
    _, wo_rolled = forward(g, 0, 30, 90, 90).directions()
    assert wo_rolled[0, 2] == pytest.approx(wo[0, 2])  # roll keeps the polar angle, changes the azimuth
    phi = np.degrees(np.arctan2(wo_rolled[0, 1], wo_rolled[0, 0]) - np.arctan2(wo[0, 1], wo[0, 0]))
    assert abs((phi + 180) % 360 - 180) == pytest.approx(90.0)


def test_offsets_move_the_sample_centre_as_declared():
    standoff = RigGeometry(sample_standoff_mm=25.4)
    p = forward(standoff, 0, 0, 0, 90)
    assert p.camera_center_mm[0, 2] == pytest.approx(1084.0 - 25.4)  # the carrier is 1 inch nearer the camera
    shifted = RigGeometry(sample_standoff_mm=0.0, tilt_axis_offset_mm=(0.0, 0.0, 12.0))
    q = forward(shifted, 0, 0, 0, 90)
    assert q.camera_center_mm[0, 1] == pytest.approx(-12.0)  # sample 12 mm up: camera 12 mm down along v
    centred = RigGeometry(sample_standoff_mm=0.0, sample_center_offset_mm=(10.0, 0.0))
    r = forward(centred, 0, 0, 0, 90)
    assert r.camera_center_mm[0, 0] == pytest.approx(-10.0)
    # Rolling a sample mounted off the roll axis moves its centre on a circle of that radius
    rolled = forward(centred, 0, 0, np.arange(0, 360, 30), 90)
    dist = np.linalg.norm(rolled.sample_to_lab_t, axis=-1)
    np.testing.assert_allclose(dist, 10.0)
    zero = forward(RigGeometry(pan_zero_deg=5.0), 5.0, 0, 0, 90)
    np.testing.assert_allclose(zero.camera_R, forward(RigGeometry(), 0, 0, 0, 90).camera_R, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(g=offsets, a=angles)
def test_extrinsics_are_rigid_and_consistent(g, a):
    p = forward(g, *a)
    R, t = p.camera_R[0], p.camera_t[0]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(-R.T @ t, p.camera_center_mm[0], atol=1e-9)
    # Distances are frame-independent: light and camera stay on their arm and rail
    c = p.sample_to_lab_t[0]
    A = p.sample_to_lab_R[0]
    light_lab = A @ p.light_pos_mm[0] + c
    assert np.hypot(*light_lab[:2]) == pytest.approx(g.light_distance_mm)
    cam_lab = A @ p.camera_center_mm[0] + c
    np.testing.assert_allclose(cam_lab, [g.camera_distance_mm, 0, g.camera_height_mm], atol=1e-9)
    # The camera looks at the rotation centre: its optical axis passes through the lab origin
    origin_cam = R @ (A.T @ (-c)) + t
    np.testing.assert_allclose(origin_cam[:2], 0.0, atol=1e-8)


@settings(max_examples=40, deadline=None)
@given(g=offsets, a=angles)
def test_inverse_recovers_directions_and_angles(g, a):
    wi, wo = forward(g, *a).directions()
    solution = inverse(g, wi, wo)
    assert solution.reachable[0], solution.error_deg
    assert solution.error_deg[0] < 1e-3
    np.testing.assert_allclose(solution.angles_deg[0], a, atol=1e-4)


def test_inverse_is_vectorised_and_reports_what_the_rig_cannot_do():
    g = RigGeometry()
    rng = np.random.default_rng(1)
    a = np.stack([rng.uniform(-60, 60, 500), rng.uniform(-60, 60, 500), rng.uniform(-170, 170, 500),
                  rng.uniform(15, 170, 500)], axis=-1)
    wi, wo = forward(g, *a.T).directions()
    s = inverse(g, wi, wo)
    assert s.reachable.all() and s.angles_deg.shape == (500, 4)
    np.testing.assert_allclose(s.angles_deg, a, atol=1e-4)
    # light and camera 5 degrees apart: the arm cannot come that close to the camera (10 deg minimum)
    near = np.array([[np.sin(np.radians(5)), 0, np.cos(np.radians(5))]])
    assert not inverse(g, near, [[0, 0, 1]]).reachable[0]
    tight = RigGeometry(pan_limits_deg=(-10, 10), tilt_limits_deg=(-10, 10))  # camera stays near the normal
    steep = [[np.sin(np.radians(50)), 0, np.cos(np.radians(50))]]
    assert not inverse(tight, [[0, 0, 1]], [[0, -np.sin(np.radians(50)), np.cos(np.radians(50))]]).reachable[0]
    assert inverse(tight, steep, [[0, 0, 1]]).reachable[0]


def test_manifest_poses_follow_the_capture_format():
    poses = forward(RigGeometry(), [0, 10], [0, 20], 0, [30, 60]).manifest_poses()
    assert [p["id"] for p in poses] == [0, 1]
    assert set(poses[1]) == {"id", "light_pos_mm", "camera", "motors"}
    assert np.asarray(poses[1]["camera"]["R"]).shape == (3, 3) and len(poses[1]["camera"]["t"]) == 3
    assert poses[1]["motors"]["light_deg"] == 60.0
