"""Sample-frame geometry: texel centres and per-texel light and view directions.

Conventions (DESIGN.md): millimetres; the sample plane is z = 0, +z its normal,
+x along texel u, +y along texel v; the origin is the centre of the sample
area; directions point away from the surface.  Array index order is ``[v, u]``.
"""

from __future__ import annotations

import functools

import numpy as np

from ._compiled import worth_compiling


def texel_centres(texels_uv: tuple[int, int], size_mm: tuple[float, float],
                  v0: int = 0, v1: int | None = None, u0: int = 0, u1: int | None = None) -> np.ndarray:
    """Texel-centre positions ``(V', U', 3)`` in mm for rows ``v0:v1`` and columns ``u0:u1``.

    >>> texel_centres((2, 2), (10.0, 10.0))[0, 0]
    array([-2.5, -2.5,  0. ])
    """
    n_u, n_v = texels_uv
    v1 = n_v if v1 is None else v1
    u1 = n_u if u1 is None else u1
    x = (np.arange(u0, u1) + 0.5) / n_u * size_mm[0] - size_mm[0] / 2
    y = (np.arange(v0, v1) + 0.5) / n_v * size_mm[1] - size_mm[1] / 2
    p = np.zeros((v1 - v0, u1 - u0, 3))
    p[..., 0] = x[None, :]
    p[..., 1] = y[:, None]
    return p


def directions_to(points: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions and distances from ``points (..., 3)`` to ``targets (P, 3)``.

    Returns ``(omega (..., P, 3), r (..., P))``.  Coincident points give a zero
    distance and the +z direction rather than NaN.
    """
    d = targets[(None,) * (points.ndim - 1)] - points[..., None, :]
    r = np.sqrt(np.einsum("...i,...i->...", d, d))  # several times faster than np.linalg.norm here
    zero = r == 0
    d /= np.where(zero, 1.0, r)[..., None]
    if zero.any():
        d[zero] = (0.0, 0.0, 1.0)
    return d, r


def tile_directions(texels_uv: tuple[int, int], size_mm: tuple[float, float], rows: tuple[int, int], cols: tuple[int, int],
                    light_pos: np.ndarray, camera_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ω_i, light distance r and ω_o for every texel of a tile, flattened to ``T = rows × cols``.

    ``rows``/``cols`` are ``(start, stop)`` as in dask's ``block_info[...]["array-location"]``;
    ``light_pos``, ``camera_pos`` are ``(P, 3)``.  Returns ``(T, P, 3)``, ``(T, P)``, ``(T, P, 3)``.
    """
    p = texel_centres(texels_uv, size_mm, rows[0], rows[1], cols[0], cols[1]).reshape(-1, 3)
    light, camera = np.asarray(light_pos, float).reshape(-1, 3), np.asarray(camera_pos, float).reshape(-1, 3)
    if worth_compiling(p.shape[0] * light.shape[0]) and p.dtype == light.dtype == camera.dtype == np.float64:
        # One pass instead of NumPy's several, the same values to an ulp (tests/core/test_geometry.py).
        return _compiled_directions()(p, np.ascontiguousarray(light), np.ascontiguousarray(camera))
    wi, r = directions_to(p, light)
    wo, _ = directions_to(p, camera)
    return wi, r, wo


@functools.cache
def _compiled_directions():
    """:func:`tile_directions` after its texel centres, compiled (numba, cached on disk).  Why: NumPy's passes
    over ``(T, P, 3)`` arrays with a trailing axis of 3 were a tenth of a Lafortune Fit tile (py-spy)."""
    from sbrdf_core.geometry_compiled import kernel

    return kernel


def camera_centre(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Camera centre ``-Rᵀ t`` from OpenCV world-to-camera extrinsics (broadcast over poses)."""
    return -np.einsum("...ji,...j->...i", R, t)


def look_at(eye: np.ndarray, target: np.ndarray = np.zeros(3), up: np.ndarray = np.array([0.0, 1.0, 0.0])) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV extrinsics ``(R, t)`` of a camera at ``eye`` looking at ``target``.

    Camera axes: +z forward, +x right, +y down.  When ``up`` is parallel to the
    view direction, another up vector is chosen instead of producing NaN.
    """
    eye = np.asarray(eye, float)
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    upv = np.asarray(up, float)
    if abs(np.dot(f, upv)) > 0.999:
        upv = np.array([1.0, 0.0, 0.0])
    x = np.cross(f, upv)
    x /= np.linalg.norm(x)
    y = np.cross(f, x)
    R = np.stack([x, y, f])
    return R, -R @ eye


def polar_direction(theta, phi) -> np.ndarray:
    """Unit direction(s) at polar angle ``theta`` from +z and azimuth ``phi`` from +x (radians, broadcast), ``(..., 3)``."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, np.float64), np.asarray(phi, np.float64))
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


def fibonacci_hemisphere(n: int, max_theta_deg: float = 80.0, offset: float = 0.0) -> np.ndarray:
    """``n`` roughly uniform unit directions on the upper hemisphere, θ ≤ ``max_theta_deg``."""
    i = np.arange(n) + 0.5
    cos_max = np.cos(np.radians(max_theta_deg))
    z = 1 - (1 - cos_max) * i / n
    phi = np.pi * (3 - np.sqrt(5)) * i + offset
    s = np.sqrt(np.clip(1 - z * z, 0, None))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def mirror_pairs(max_theta: float, n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """The mirror pairs ``(ω_i, ω_o)`` where :func:`~sbrdf_core.constraints.mirror_peak` looks: ``n`` elevations up to ``max_theta``
    in two azimuths, ``(2n, 3)`` each (what the fitting engine's compiled widening reads too)."""
    th = np.linspace(0.0, max_theta, n)
    d = np.concatenate([polar_direction(th, phi) for phi in (0.0, np.pi / 2)])
    return d, d * [-1, -1, 1]
