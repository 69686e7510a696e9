"""Forward and inverse kinematics of McAllister's four-motor spatial gonioreflectometer.

The thesis (seed 000, §3.2, Fig 3.1–3.2) fixes the camera on an optical rail,
swings the light on an arm in the plane of the optical bench, and carries the
sample on a pan motor, then a tilt motor, then a roll motor.  It does not give
the kinematic chain or its offsets (notes §18.1), so this module makes them
parameters (:class:`RigGeometry`) and derives from four motor angles:

* the light position in the sample frame (``light_pos_mm``), and
* the camera extrinsics (OpenCV world-to-camera ``R``, ``t``; world = sample frame),

vectorised over any number of poses; :func:`inverse` finds the motor angles
for a wanted direction pair (ω_i, ω_r) at the sample centre where the rig can
reach it.

Shared by the rig's capture source and planner (``sbrdf_capture``) and by any
plugin that simulates the rig's geometry (``sbrdf_shading``'s arc capture).

Frames
------
*Lab*: origin where the pan axis meets the tilt axis; ``+Z`` up along the pan
axis; ``+X`` from the origin towards the camera.  The light arm turns about
the pan axis: arm angle ``a`` puts the light at
``(d_l cos a, d_l sin a, h_l)``, ``a`` measured from the camera direction
(the thesis' arc runs from 10° to 175° from the camera).

*Sample*: the sample plane is ``z = 0``, ``+z`` its normal, as everywhere in
sbrdf.  At the zero pose the normal faces the camera (``+z_s = +X``), texel
``u`` (``+x_s``) runs along ``+Y`` and ``v`` (``+y_s``) points up (``+Z``).

Chain, outermost first::

    p_lab = Rz(pan) · ( o_tilt + Ry(−tilt) · ( s·X + Rx(roll) · B · (p_s + o_c) ) )

with ``B`` the zero-pose orientation above, ``o_tilt`` the tilt axis' offset
from the pan axis (pan frame), ``s`` the sample surface's stand-off from the
tilt axis along the normal (the thesis' carrier sits one inch, 25.4 mm, from
the tilt axis, §3.3) and ``o_c`` the sample centre's offset from the roll
axis, in sample coordinates.  Positive tilt lifts the normal towards ``+Z``;
roll spins the sample about its normal; each motor angle is reduced by its
``*_zero_deg`` (encoder zero) before use.

The camera sits at ``(d_c, 0, h_c)`` and looks at the lab origin with ``+Z``
up; its OpenCV axes are x right, y down, z forward.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["MOTORS", "InverseSolution", "RigGeometry", "RigPoses", "forward", "inverse"]

_X = np.array([1.0, 0.0, 0.0])
#: Zero-pose sample orientation: columns are the sample axes x_s, y_s, z_s in lab coordinates.
_B = np.array([[0.0, 0.0, 1.0],
               [1.0, 0.0, 0.0],
               [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class RigGeometry:
    """Dimensions, axis offsets, encoder zeros and motor ranges of the rig (mm, degrees).

    The defaults follow the thesis: the camera 1084 mm away (a 300 mm field
    with the 50 mm lens, Table 3.3), the light on a one-metre arm swinging
    10°–175° from the camera, the carrier 25.4 mm in front of the tilt axis.
    """

    camera_distance_mm: float = 1084.0
    light_distance_mm: float = 1000.0
    camera_height_mm: float = 0.0
    light_height_mm: float = 0.0
    tilt_axis_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sample_standoff_mm: float = 25.4
    sample_center_offset_mm: tuple[float, float] = (0.0, 0.0)
    pan_zero_deg: float = 0.0
    tilt_zero_deg: float = 0.0
    roll_zero_deg: float = 0.0
    light_zero_deg: float = 0.0
    pan_limits_deg: tuple[float, float] = (-170.0, 170.0)
    tilt_limits_deg: tuple[float, float] = (-80.0, 80.0)
    roll_limits_deg: tuple[float, float] = (-180.0, 180.0)
    light_limits_deg: tuple[float, float] = (10.0, 175.0)

    @property
    def limits(self) -> np.ndarray:
        """``(4, 2)`` motor limits, rows pan, tilt, roll, light."""
        return np.array([self.pan_limits_deg, self.tilt_limits_deg, self.roll_limits_deg, self.light_limits_deg],
                        dtype=float)

    @property
    def zeros(self) -> np.ndarray:
        return np.array([self.pan_zero_deg, self.tilt_zero_deg, self.roll_zero_deg, self.light_zero_deg])


MOTORS = ("pan_deg", "tilt_deg", "roll_deg", "light_deg")


@dataclass(frozen=True)
class RigPoses:
    """Light and camera for N poses, in the sample frame (mm); from :func:`forward`.

    ``angles_deg`` is ``(N, 4)``: pan, tilt, roll, light motor angles.
    ``camera_R``/``camera_t`` are OpenCV world-to-camera extrinsics
    (``x_cam = R x_sample + t``); ``camera_center_mm = −Rᵀ t``.
    """

    angles_deg: np.ndarray
    light_pos_mm: np.ndarray
    camera_R: np.ndarray
    camera_t: np.ndarray
    camera_center_mm: np.ndarray
    sample_to_lab_R: np.ndarray = field(repr=False)
    sample_to_lab_t: np.ndarray = field(repr=False)

    def __len__(self) -> int:
        return len(self.angles_deg)

    def directions(self, point_mm=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Unit ω_i (to the light) and ω_r (to the camera) at a sample-frame point, ``(N, 3)`` each."""
        p = np.asarray(point_mm, dtype=float)
        return _unit(self.light_pos_mm - p), _unit(self.camera_center_mm - p)

    def manifest_poses(self) -> list[dict]:
        """The poses as ``sbrdf-capture/1`` manifest entries (without exposures)."""
        return [{"id": i, "light_pos_mm": self.light_pos_mm[i].tolist(),
                 "camera": {"R": self.camera_R[i].tolist(), "t": self.camera_t[i].tolist()},
                 "motors": dict(zip(MOTORS, self.angles_deg[i].tolist()))}
                for i in range(len(self))]


# -- rotations -----------------------------------------------------------------------------------------------------


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    """Right-handed rotations about lab axis 0/1/2 by ``angle`` (radians), ``(N, 3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    n = np.shape(angle)[0]
    R = np.zeros((n, 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[:, axis, axis] = 1.0
    R[:, i, i] = c
    R[:, j, j] = c
    R[:, i, j] = -s
    R[:, j, i] = s
    return R


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _camera_in_lab(geometry: RigGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Lab-to-camera rotation (rows: camera x, y, z in lab coordinates) and camera centre."""
    centre = np.array([geometry.camera_distance_mm, 0.0, geometry.camera_height_mm])
    forward = _unit(-centre)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward]), centre


# -- forward -----------------------------------------------------------------------------------------------------


def forward(geometry: RigGeometry, pan_deg=0.0, tilt_deg=0.0, roll_deg=0.0, light_deg=90.0) -> RigPoses:
    """Light position and camera extrinsics in the sample frame for motor angles (broadcast to N poses)."""
    pan, tilt, roll, light = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, dtype=float))
                                                   for a in (pan_deg, tilt_deg, roll_deg, light_deg)))
    angles = np.stack([pan, tilt, roll, light], axis=-1).reshape(-1, 4)
    q = np.deg2rad(angles - geometry.zeros)
    Rp, Rt, Rr = _rot(2, q[:, 0]), _rot(1, -q[:, 1]), _rot(0, q[:, 2])
    A = Rp @ Rt @ Rr @ _B                                      # sample -> lab rotation
    o_c = np.array([*geometry.sample_center_offset_mm, 0.0])
    inner = geometry.sample_standoff_mm * _X + np.einsum("nij,j->ni", Rr @ _B, o_c)
    c = np.einsum("nij,nj->ni", Rp, np.asarray(geometry.tilt_axis_offset_mm, float) + np.einsum("nij,nj->ni", Rt, inner))
    light_lab = np.stack([geometry.light_distance_mm * np.cos(q[:, 3]), geometry.light_distance_mm * np.sin(q[:, 3]),
                          np.full(len(q), geometry.light_height_mm)], axis=-1)
    At = np.transpose(A, (0, 2, 1))
    light_s = np.einsum("nij,nj->ni", At, light_lab - c)
    R_cl, C_lab = _camera_in_lab(geometry)
    R = R_cl @ A
    t = np.einsum("ij,nj->ni", R_cl, c - C_lab)
    centre = np.einsum("nij,nj->ni", At, C_lab - c)
    return RigPoses(angles, light_s, R, t, centre, A, c)


# -- inverse -----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class InverseSolution:
    """Motor angles for wanted direction pairs; see :func:`inverse`."""

    angles_deg: np.ndarray       # (N, 4) pan, tilt, roll, light
    reachable: np.ndarray        # (N,) bool: within limits and within ``tolerance_deg``
    error_deg: np.ndarray        # (N,) largest angle between wanted and achieved ω_i / ω_r


def _analytic(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Exact angles for a rig without offsets (both sources at the rotation centre's height)."""
    cos_a = np.clip(np.einsum("ni,ni->n", wi, wo), -1.0, 1.0)
    e2 = wi - cos_a[:, None] * wo
    norm = np.linalg.norm(e2, axis=-1, keepdims=True)
    fallback = np.cross(wo, [0.0, 0.0, 1.0]) + np.cross(wo, [1.0, 0.0, 0.0]) * 1e-3
    e2 = np.where(norm > 1e-9, e2 / np.maximum(norm, 1e-12), _unit(fallback))
    A = np.stack([wo, e2, np.cross(wo, e2)], axis=1)           # sample -> lab: wo -> X, wi -> (cos a, sin a, 0)
    M = A @ _B.T                                                 # = Rz(pan) Ry(-tilt) Rx(roll)
    theta = -np.arcsin(np.clip(M[:, 2, 0], -1.0, 1.0))
    pan = np.arctan2(M[:, 1, 0], M[:, 0, 0])
    roll = np.arctan2(M[:, 2, 1], M[:, 2, 2])
    return np.rad2deg(np.stack([pan, -theta, roll, np.arccos(cos_a)], axis=-1))


def _wrap(deg: np.ndarray) -> np.ndarray:
    return (deg + 180.0) % 360.0 - 180.0


def inverse(geometry: RigGeometry, wi, wo, *, iterations: int = 12, tolerance_deg: float = 1e-3,
            point_mm=(0.0, 0.0, 0.0)) -> InverseSolution:
    """Motor angles that put the light along ``wi`` and the camera along ``wo`` (sample frame, at ``point_mm``).

    Solved exactly for a rig without offsets, then refined by a batched
    Gauss–Newton on all poses at once for the offsets, heights and encoder
    zeros of ``geometry``.  Pairs the rig cannot realise (a light–camera angle
    outside the arm's range, a motor outside its limits) come back with
    ``reachable = False``.
    """
    wi = _unit(np.atleast_2d(np.asarray(wi, dtype=float)))
    wo = _unit(np.atleast_2d(np.asarray(wo, dtype=float)))
    q = _analytic(wi, wo) + geometry.zeros
    target = np.concatenate([wi, wo], axis=-1)

    def residual(angles: np.ndarray) -> np.ndarray:
        a, b = forward(geometry, *angles.T).directions(point_mm)
        return np.concatenate([a, b], axis=-1) - target

    h = 1e-4
    for _ in range(iterations):
        r = residual(q)
        if np.max(np.abs(r)) < 1e-12:
            break
        J = np.empty((len(q), 6, 4))
        for k in range(4):
            step = np.zeros(4)
            step[k] = h
            J[:, :, k] = (residual(q + step) - residual(q - step)) / (2 * h)
        JtJ = np.einsum("nik,nil->nkl", J, J) + 1e-9 * np.eye(4)
        delta = np.linalg.solve(JtJ, -np.einsum("nik,ni->nk", J, r)[..., None])[..., 0]
        q = q + np.clip(delta, -20.0, 20.0)
    q[:, :3] = _wrap(q[:, :3])
    a, b = forward(geometry, *q.T).directions(point_mm)
    error = np.rad2deg(np.maximum(np.arccos(np.clip(np.einsum("ni,ni->n", a, wi), -1, 1)),
                                  np.arccos(np.clip(np.einsum("ni,ni->n", b, wo), -1, 1))))
    lim = geometry.limits
    inside = np.all((q >= lim[:, 0] - 1e-9) & (q <= lim[:, 1] + 1e-9), axis=-1)
    return InverseSolution(q, inside & (error <= tolerance_deg), error)
