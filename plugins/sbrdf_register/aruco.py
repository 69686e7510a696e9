"""aruco: fiducial registration of real (or virtual) photographs onto the texel grid.

McAllister's scanner (seed 000 §3.6, notes §4) knows each pose only as well as
its motors do: up to ≈3 mm on the sample, a dozen texels.  Printed fiducials
around the sample measure where the sample really is in every photograph, so
this plugin, per pose:

1. **detects** the carrier's ArUco markers (``cv2.aruco``, dictionary from the
   capture's ``sample.fiducials``) on a tone-mapped 8-bit copy of the linear
   HDR image, with sub-pixel corner refinement;
2. **undistorts** the corners (``cv2.undistortPoints`` with the capture's K and
   dist) so a plane maps to the ideal image by a homography;
3. fits the **homography** sample-plane mm → undistorted pixel by least squares
   (``cv2.findHomography``, method 0, as the text does) and reports its **RMS
   residual in mm** on the sample plane (corners mapped back through H⁻¹);
4. recovers the **camera pose** from the same corners (``cv2.solvePnP``, IPPE
   for planar targets, then Levenberg–Marquardt refinement), so the camera
   centre used for ω_r is measured, not the nominal motor one; the nominal
   light is carried into the measured sample frame with the same pose error
   (the rig's camera and light are fixed in the lab, the sample is what moves);
5. **rejects** poses it cannot trust, with the reason listed in the
   RegisteredStack's ``rejected`` attribute: nominal camera behind the sample,
   an unusable (black, non-finite) image, too few markers, RMS over
   ``max_rms_mm``, a measured camera behind the sample, a measured pose too far
   from the nominal one.

Resampling (:meth:`ArucoRegistration.resample`, one pose per call, a block of poses per dask task) maps
every texel through H and the lens distortion into the photograph and samples
it with bicubic interpolation (``cv2.remap``).  When a texel covers more than a
pixel (the camera is close, or the sample is seen at a grazing angle so the
footprint is long in one direction) plain point sampling would alias, so the
footprint — the columns of the mapping's local Jacobian, in pixels — chooses a
pyramid level (``cv2.pyrDown``, a Gaussian pre-blur per octave) and a number
of bicubic sub-samples along u and v inside the texel (an anisotropic box
filter in texture space) that are averaged.  When the camera sees fewer pixels
than texels, bicubic interpolation alone is right; the stack then simply
holds less detail than its grid suggests, and the pixels-per-texel figures are
recorded so users can see it.

At the sample edge (``edge: renormalise``, the default) the filter is clipped
and renormalised: pixels off the sample rectangle or within ``edge_margin_px``
of its edge (where lens blur mixes in the carrier) are not *usable*; a
sub-sample whose bicubic support touches one of them, or the image border, is
instead interpolated bilinearly from the usable pixels only, weights
renormalised (normalised convolution, ``remap(image·usable) / remap(usable)``
through the same pyramid), and weighs what it found.  A texel is the weighted
mean of its sub-samples, valid when at least ``edge_min_weight`` of its filter
weight fell on usable pixels, so the outer texel rings are kept (on the
virtual-scan capture 375 of 4096 texels, the outer ring and half the second,
had no sample at all under the former rule, ``edge: strict``: any pixel the
filter touches off the sample or outside the image invalidates the texel).

A texel sample is invalid (``valid`` false) when any pixel its filter touches
is saturated or under-exposed (the capture's ``valid`` mask: never renormalised
away, dropping a highlight's brightest pixels would bias it), when too little
of its filter falls on usable pixels (``strict``: when any pixel it touches is
off the sample or outside the image), or when the texel faces away from the
camera.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_core.geometry import camera_centre
from sbrdf_core.nodes.base import shared
from sbrdf_core.types import Registration

from .declarations import ARUCO

logger = logging.getLogger(__name__)

#: Pixels of bicubic support on each side of a sample point (the kernel is 4×4).
BICUBIC_RADIUS = 2


#: Most bytes of float32 remap maps ``resample`` holds for all of a pose's sub-samples at once (to
#: crop the photograph to what they reach); past it, each sub-sample's maps are made in turn, uncropped.
MAPS_HELD_BYTES = 32 << 20

#: Most poses measured per dask task (see ``register``): one photograph is in memory at a time.
MEASURE_BLOCK = 32

#: One pose's measurement, as a task returns it: fixed-size fields, so a block of poses is
#: one small array (a few hundred bytes a pose), not a Python object per pose.  ``level``,
#: ``n_u``, ``n_v`` and ``px_per_texel`` are the resampling filter (:func:`footprint`).
FIT_DTYPE = np.dtype([
    ("pose", np.int64), ("ok", bool), ("markers", np.int32), ("H", np.float64, (3, 3)), ("rms_mm", np.float64),
    ("reproj_px", np.float64), ("R", np.float64, (3, 3)), ("t", np.float64, (3,)),
    ("level", np.int32), ("n_u", np.int32), ("n_v", np.int32), ("px_per_texel", np.float64),
])


@dataclass
class PoseFit:
    """What detection measured for one pose (``ok`` false: ``reason`` says why)."""

    pose: int
    ok: bool
    reason: str = ""
    markers: int = 0
    H: np.ndarray | None = None  # sample mm -> undistorted pixel
    rms_mm: float = float("nan")
    reproj_px: float = float("nan")
    R: np.ndarray | None = None  # measured world-to-camera rotation
    t: np.ndarray | None = None


# ---------------------------------------------------------------------------
# camera model helpers (vectorised, no per-pixel Python)
# ---------------------------------------------------------------------------


def distortion_terms(dist) -> np.ndarray:
    """OpenCV's ``(k1, k2, p1, p2, k3)`` from a capture's distortion coefficients: missing terms 0, terms past
    the fifth (thin prism, tilt) not modelled."""
    k = np.zeros(5)
    k[: min(5, len(dist))] = np.asarray(dist, float)[:5]
    return k


def distort(xn: np.ndarray, yn: np.ndarray, K: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised ideal coordinates -> distorted pixel coordinates (OpenCV's 5-term model)."""
    k = distortion_terms(dist)
    k1, k2, p1, p2, k3 = k
    r2 = xn * xn + yn * yn
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
    return K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]


def plane_to_pixels(xy_mm: np.ndarray, H: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Sample-plane points ``(..., 2)`` mm -> distorted pixel coordinates ``(..., 2)`` through H then the lens.

    Points behind the camera (homogeneous w ≤ 0) come back as NaN.
    """
    x, y = xy_mm[..., 0], xy_mm[..., 1]
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w
        v = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
    u = np.where(w > 0, u, np.nan)
    v = np.where(w > 0, v, np.nan)
    Ki = np.linalg.inv(K)
    xn = Ki[0, 0] * u + Ki[0, 1] * v + Ki[0, 2]
    yn = Ki[1, 1] * v + Ki[1, 2]
    pu, pv = distort(xn, yn, K, dist)
    return np.stack([pu, pv], axis=-1)


def grid_to_pixels(xs: np.ndarray, ys: np.ndarray, H: np.ndarray, K: np.ndarray, dist: np.ndarray,
                   compiled: bool = False) -> np.ndarray:
    """:func:`plane_to_pixels` of the grid ``xs × ys`` (mm), ``(len(ys), len(xs), 2)``: every texel of a pose.

    ``compiled``: one numba loop (a texel's ~40 flops in registers, not ~40 NumPy passes over
    the grid, each writing a temporary as large as the grid), the same arithmetic in the
    same order, so the same bits; loading numba costs about 80 MB in the process (the aruco
    parameter ``compiled_mapping``).
    """
    xs, ys = np.asarray(xs, np.float64), np.asarray(ys, np.float64)
    K, H = np.asarray(K, np.float64), np.asarray(H, np.float64)
    if not compiled:
        return np.stack(_grid_xy(xs, ys, H, K, dist), axis=-1)
    k = distortion_terms(dist)
    out = np.empty((2, len(ys), len(xs)))
    _grid_kernel()(np.ascontiguousarray(H), np.linalg.inv(K), np.ascontiguousarray(K), k, np.ascontiguousarray(xs),
                   np.ascontiguousarray(ys), False, 1.0, out[0], out[1])
    return np.moveaxis(out, 0, -1)


#: remap's map entry for a point with no usable pixel (behind the camera, or overflowing float32): far off the image.
OFF_IMAGE = -1e6


def _mark_off_image(m: np.ndarray) -> None:
    """Set the non-finite entries of the float32 map ``m`` to :data:`OFF_IMAGE`, in place."""
    finite = np.isfinite(m)
    if not finite.all():
        m[~finite] = np.float32(OFF_IMAGE)


def remap_maps(xs: np.ndarray, ys: np.ndarray, H: np.ndarray, K: np.ndarray, dist: np.ndarray, scale: float,
               compiled: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap``'s float32 maps of the grid ``xs × ys`` (mm) at pyramid scale ``scale`` (1, 1/2, ...).

    Pixel centres at level l: x_l = (x + 0.5)·2^-l − 0.5; points with no finite pixel (behind the
    camera) get :data:`OFF_IMAGE`, far off the image.  ``compiled``: as :func:`grid_to_pixels`, the same bits.
    """
    if not compiled:
        maps = np.empty((2, len(ys), len(xs)), np.float32)
        for rows, *ps in _grid_blocks(np.asarray(xs, np.float64), np.asarray(ys, np.float64),
                                      np.asarray(H, np.float64), np.asarray(K, np.float64), dist):
            for m, p in zip(maps, ps):
                p += 0.5
                p *= scale
                p -= 0.5
                m = m[rows]
                m[...] = p  # float64 -> float32, as astype
                _mark_off_image(m)
        return maps[0], maps[1]
    K = np.asarray(K, np.float64)
    k = distortion_terms(dist)
    out = np.empty((2, len(ys), len(xs)), np.float32)
    _grid_kernel()(np.ascontiguousarray(H, np.float64), np.linalg.inv(K), np.ascontiguousarray(K), k,
                   np.ascontiguousarray(xs, np.float64), np.ascontiguousarray(ys, np.float64), True, float(scale),
                   out[0], out[1])
    return out[0], out[1]


def texel_maps(texels_uv, size_mm, offset: tuple[float, float], H: np.ndarray, K: np.ndarray, dist: np.ndarray,
               scale: float, compiled: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """:func:`remap_maps` of the texel grid at sub-sample ``offset`` (texels, see :func:`_texel_axes`).

    Why OpenCV: the grid's axes are affine in the texel index, so texel → normalised camera
    coordinates is one 3×3 matrix (K⁻¹·H·A), and ``cv2.initUndistortRectifyMap`` applies exactly
    that, then the same 5-term distortion and K, in float64 SIMD lanes on OpenCV's threads, in one pass
    where NumPy makes one per operation.  It rounds
    differently inside float64, so a float32 map entry may differ from :func:`remap_maps`' by an ulp
    (of 1 px near 0, where the distortion's terms cancel; tested).  It has no skew term and does not mark points behind the camera, so a skewed K, a grid
    reaching behind the camera or anything non-finite goes to :func:`remap_maps`, as does
    ``compiled`` (numba, the NumPy bits).
    """
    xs, ys = _texel_axes(texels_uv, size_mm, *offset)
    H, K = np.asarray(H, np.float64), np.asarray(K, np.float64)
    if compiled or not _opencv_maps_apply(xs, ys, H, K, dist):
        return remap_maps(xs, ys, H, K, dist, scale, compiled)
    return _opencv_texel_maps(texels_uv, size_mm, offset, H, K, dist, scale)


def _opencv_texel_maps(texels_uv, size_mm, offset: tuple[float, float], H: np.ndarray, K: np.ndarray,
                       dist: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`texel_maps` by OpenCV, where :func:`_opencv_maps_apply` says it may (float64 ``H`` and ``K``)."""
    import cv2

    (U, V), (sx, sy), (ou, ov) = texels_uv, size_mm, offset
    # x_j = (j + 0.5 + ou)/U·sx − sx/2 = a_x·j + b_x (and y alike): the grid is A·(j, i, 1).
    A = np.array([[sx / U, 0.0, (0.5 + ou) / U * sx - sx / 2], [0.0, sy / V, (0.5 + ov) / V * sy - sy / 2],
                  [0.0, 0.0, 1.0]])
    to_normalised = np.linalg.inv(K) @ H @ A  # OpenCV applies inv(newCameraMatrix · R): give it the inverse
    k = distortion_terms(dist)
    # K at pyramid scale, with remap_maps' (p + 0.5)·scale − 0.5 folded into the principal point.
    K_level = np.array([[K[0, 0] * scale, 0.0, (K[0, 2] + 0.5) * scale - 0.5],
                        [0.0, K[1, 1] * scale, (K[1, 2] + 0.5) * scale - 0.5], [0.0, 0.0, 1.0]])
    maps = cv2.initUndistortRectifyMap(K_level, k, None, np.linalg.inv(to_normalised), (U, V), cv2.CV_32FC1)
    for m in maps:  # a point in front of the camera whose pixel overflows float32: remap_maps' sentinel
        _mark_off_image(m)
    return maps


def _opencv_maps_apply(xs: np.ndarray, ys: np.ndarray, H: np.ndarray, K: np.ndarray, dist) -> bool:
    """Whether OpenCV's map is :func:`remap_maps`' (see :func:`texel_maps`): no skew, finite terms, every texel
    in front of the camera (w is affine over the grid, so its least value is at a corner)."""
    if len(xs) < 2 or len(ys) < 2 or K[0, 1] != 0 or np.any(K[2] != (0.0, 0.0, 1.0)):
        return False
    if not (np.isfinite(H).all() and np.isfinite(K).all() and np.isfinite(np.asarray(dist, float)).all()):
        return False
    cx, cy = np.array([xs[0], xs[-1], xs[0], xs[-1]]), np.array([ys[0], ys[0], ys[-1], ys[-1]])
    return bool(np.all(H[2, 0] * cx + H[2, 1] * cy + H[2, 2] > 0))


#: Texels per block of rows of the NumPy mapping (:func:`_grid_blocks`): a block's dozen float64
#: temporaries (64 KB each) stay in the core's cache and in malloc's reused heap.  Whole-grid passes
#: (512 KB arrays at 256² texels) were memory-bound and, being fresh mmap'd allocations, page-faulted
#: on every call: about 2x the time of the arithmetic.
GRID_BLOCK = 8192


def _grid_blocks(xs: np.ndarray, ys: np.ndarray, H: np.ndarray, K: np.ndarray, dist: np.ndarray):
    """:func:`_grid_xy` a block of rows at a time: yields ``(rows, px, py)``, ``rows`` a slice of ``ys``."""
    k = distortion_terms(dist)
    Ki = np.linalg.inv(K)
    step = max(1, GRID_BLOCK // max(1, len(xs)))
    for i in range(0, len(ys), step):
        rows = slice(i, min(len(ys), i + step))
        yield (rows, *_grid_rows(xs, ys[rows], H, K, k, Ki))


def _grid_xy(xs: np.ndarray, ys: np.ndarray, H: np.ndarray, K: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`plane_to_pixels` of a grid, ``(px, py)``, in NumPy: term for term the same arithmetic (the
    same bits), the homography's terms per row and column, every pass in place, a block of rows at a time."""
    px, py = np.empty((len(ys), len(xs))), np.empty((len(ys), len(xs)))
    for rows, bx, by in _grid_blocks(xs, ys, H, K, dist):
        px[rows], py[rows] = bx, by
    return px, py


def _grid_rows(xs: np.ndarray, ys: np.ndarray, H: np.ndarray, K: np.ndarray, k: np.ndarray,
               Ki: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_grid_xy` of the rows ``ys`` (``k``: the five distortion terms, ``Ki``: K⁻¹)."""
    k1, k2, p1, p2, k3 = k
    X, Y = xs[None, :], ys[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = H[2, 0] * X + H[2, 1] * Y
        w += H[2, 2]
        u = H[0, 0] * X + H[0, 1] * Y
        u += H[0, 2]
        u /= w
        v = H[1, 0] * X + H[1, 1] * Y
        v += H[1, 2]
        v /= w
        behind = ~(w > 0)
        if behind.any():
            u[behind] = np.nan
            v[behind] = np.nan
        xn = Ki[0, 0] * u
        xn += Ki[0, 1] * v
        xn += Ki[0, 2]
        yn, u = u, None  # reuse u's buffer
        np.multiply(Ki[1, 1], v, out=yn)
        yn += Ki[1, 2]
        r2 = xn * xn
        r2 += yn * yn
        radial = r2 * k3  # 1 + r2·(k1 + r2·(k2 + r2·k3))
        radial += k2
        radial *= r2
        radial += k1
        radial *= r2
        radial += 1
        t = 2 * xn  # xd = xn·radial + 2·p1·xn·yn + p2·(r2 + 2·xn·xn)
        t *= xn
        t += r2
        t *= p2
        xd = xn * radial
        s = (2 * p1) * xn
        s *= yn
        xd += s
        xd += t
        np.multiply(2, yn, out=t)  # yd = yn·radial + p1·(r2 + 2·yn·yn) + 2·p2·xn·yn
        t *= yn
        t += r2
        t *= p1
        yd = yn * radial
        yd += t
        np.multiply(2 * p2, xn, out=s)
        s *= yn
        yd += s
        px = K[0, 0] * xd
        px += K[0, 1] * yd
        px += K[0, 2]
        py = K[1, 1] * yd
        py += K[1, 2]
    return px, py


@functools.cache
def _grid_kernel():
    """The compiled loop of :func:`grid_to_pixels` (numba, cached on disk: compiled once per install)."""
    import numba

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def kernel(H, Ki, K, k, xs, ys, maps, scale, out_x, out_y):  # pragma: no cover (compiled)
        k1, k2, p1, p2, k3 = k[0], k[1], k[2], k[3], k[4]
        for i in range(ys.shape[0]):
            y = ys[i]
            hy0, hy1, hy2 = H[0, 1] * y, H[1, 1] * y, H[2, 1] * y
            for j in range(xs.shape[0]):
                x = xs[j]
                # plane_to_pixels, term for term (the same rounding as its NumPy passes); selects, not
                # branches, so the loop vectorises.
                w = H[2, 0] * x + hy2 + H[2, 2]
                u = (H[0, 0] * x + hy0 + H[0, 2]) / w
                v = (H[1, 0] * x + hy1 + H[1, 2]) / w
                u = u if w > 0 else np.nan
                v = v if w > 0 else np.nan
                xn = Ki[0, 0] * u + Ki[0, 1] * v + Ki[0, 2]
                yn = Ki[1, 1] * v + Ki[1, 2]
                r2 = xn * xn + yn * yn
                radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
                xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
                yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
                px = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
                py = K[1, 1] * yd + K[1, 2]
                if maps:  # remap's float32 maps at pyramid scale ``scale``, off-image sentinel for non-finite
                    mx = np.float32((px + 0.5) * scale - 0.5)
                    my = np.float32((py + 0.5) * scale - 0.5)
                    out_x[i, j] = mx if np.isfinite(mx) else np.float32(OFF_IMAGE)
                    out_y[i, j] = my if np.isfinite(my) else np.float32(OFF_IMAGE)
                else:
                    out_x[i, j] = px
                    out_y[i, j] = py

    return kernel


#: Rec. 709 luminance weights of linear RGB (the detector's grey and the edge refinement's linear image).
LUMA = np.array([[0.2126, 0.7152, 0.0722]], np.float32)


def luminance(image: np.ndarray) -> np.ndarray:
    """Linear RGB ``(H, W, 3)`` -> ``(H, W)`` float32 luminance in one SIMD pass (``cv2.transform``); non-finite
    pixels (a broken photograph's) come back as 0."""
    import cv2

    grey = cv2.transform(np.ascontiguousarray(image, np.float32), LUMA).reshape(image.shape[:2])
    finite = np.isfinite(grey)
    if not finite.all():
        grey[~finite] = 0.0
    return grey


def tone_map(image: np.ndarray, valid: np.ndarray, grey: np.ndarray | None = None) -> np.ndarray:
    """Linear HDR RGB -> 8-bit grey for the marker detector (robust white point, gamma 1/2.2).

    ``grey``: the photograph's :func:`luminance` when the caller has it already (it is not modified).
    """
    grey = luminance(image) if grey is None else np.array(grey, np.float32)  # a copy: modified in place below
    some = bool(valid.any())
    sel = grey[valid] if some else grey.ravel().copy()  # copies: the percentile partitions them in place
    white = _percentile(sel, 99.0) if sel.size else 0.0
    if not white > 0:
        return np.zeros(grey.shape, np.uint8)
    # Saturated pixels keep their clipped value, which is bright: fine for black/white markers.
    # In place (255·clip(grey / white, 0, 1)^(1/2.2) + 0.5): no full-image temporaries.  The power is
    # exp(log(·)/2.2): NumPy's log and exp run in float32 SIMD lanes, its float32 power does not (log 0 = -inf -> 0).
    np.divide(grey, np.float32(white), out=grey)
    np.clip(grey, 0.0, 1.0, out=grey)
    with np.errstate(divide="ignore"):
        np.log(grey, out=grey)
    grey *= np.float32(1 / 2.2)
    np.exp(grey, out=grey)
    grey *= 255.0
    grey += 0.5
    return grey.astype(np.uint8)


def _percentile(values: np.ndarray, q: float) -> float:
    """``np.percentile(values, q)`` (linear interpolation) from one in-place partition of ``values`` at the two
    order statistics it needs, in place, where ``np.percentile`` first copies the whole photograph."""
    pos = q / 100.0 * (values.size - 1)
    k = int(pos)
    k1 = min(k + 1, values.size - 1)
    values.partition((k, k1))
    lo, hi = float(values[k]), float(values[k1])
    return lo + (hi - lo) * (pos - k)


# ---------------------------------------------------------------------------
# the plugin
# ---------------------------------------------------------------------------


class ArucoRegistration:
    """Register plugin ``aruco`` (see the module docstring)."""

    params = ARUCO

    #: Resample only the window of the photograph the pose's filter reaches (:meth:`_crop_window`; the
    #: same bits as the whole photograph: tests switch it off to compare).
    crop = True

    def __init__(self, *, texels=(256, 256), max_rms_mm: float = 0.5, min_markers: int = 2,
                 max_pose_deg: float | None = 10.0, pose_from: str = "fiducials", correct_light: bool = True,
                 corner_refine: str = "edges", refine_win_px: int = 5, max_subsamples: int = 4,
                 edge_margin_px: float = 2.0, edge: str = "renormalise", edge_min_weight: float = 0.25,
                 compiled_mapping: bool = False):
        self.texels = (int(texels[0]), int(texels[1]))
        self.max_rms_mm = float(max_rms_mm)
        self.min_markers = int(min_markers)
        self.max_pose_deg = max_pose_deg
        self.pose_from = pose_from
        self.correct_light = bool(correct_light)
        self.refine_win_px = int(refine_win_px)
        self.max_subsamples = int(max_subsamples)
        self.edge_margin_px = float(edge_margin_px)
        self.corner_refine = corner_refine
        self.edge = edge
        self.edge_min_weight = float(edge_min_weight)
        self.compiled_mapping = bool(compiled_mapping)

    # -- measuring (once per capture, before any resampling) --------------------------------------

    def _camera(self, capture) -> tuple[dict, np.ndarray, np.ndarray]:
        """The capture's fiducials, K and distortion; refuses captures aruco cannot register."""
        cam = capture.attrs.get("camera", {})
        sample = capture.attrs.get("sample", {})
        if cam.get("model", "pinhole") != "pinhole":
            raise SbrdfError(f"capture {capture.url}: aruco registration needs photographs (camera model 'pinhole'), "
                             f"got {cam.get('model')!r}; use texel-aligned for texel-aligned simulations")
        fid = sample.get("fiducials")
        if not fid or not fid.get("markers"):
            raise SbrdfError(f"capture {capture.url}: sample.fiducials lists no markers; aruco registration needs "
                             "the printed marker corners (capture.json sample.fiducials)")
        K = np.asarray(cam["K"], float)
        dist = np.asarray(cam.get("dist", [0] * 5), float)
        return fid, K, dist

    def prepare(self, capture) -> dict:
        """Marker detection and pose measurement of every photograph, lazily: ``{"blocks": [delayed, ...]}``.

        The runner computes it on the run's scheduler with the node's progress
        bar; :meth:`register` gets the results as ``prepared``.
        """
        import dask

        fid, K, dist = self._camera(capture)
        sample = capture.attrs.get("sample", {})
        R_nom, t_nom = capture.read("camera_R"), capture.read("camera_t")
        P = capture.zarr_array("light_pos").shape[0]
        # One task measures a block of poses, reading each photograph from the capture's
        # zarr arrays (one shared graph key each), and returns one small record array:
        # per-pose tasks or results were O(poses) task specs and Python objects, and the
        # scheduler's and client's memory grew with the scan.
        images, valids = shared(capture.zarr_array("images")), shared(capture.zarr_array("valid"))
        sample_mm = (float(sample["size_mm"][0]), float(sample["size_mm"][1]))
        fid_, K_, dist_, settings = shared(fid), shared(K), shared(dist), shared(self._detector_settings(sample_mm))
        R_, t_ = shared(R_nom), shared(t_nom)
        measure = dask.delayed(_measure_poses, pure=True)
        k = max(1, min(MEASURE_BLOCK, -(-P // 8)))  # at least 8 tasks keep every core busy on small scans
        return {"blocks": [measure(lo, min(P, lo + k), images, valids, fid_, K_, dist_, R_, t_, settings)
                           for lo in range(0, P, k)]}

    def register(self, capture, prepared: dict | None = None) -> Registration:
        """Accept or reject every pose from :meth:`prepare`'s computed ``prepared`` and build the Registration.

        Outside a run (``prepared`` not given) the measurement is computed here, on dask's default scheduler.
        """
        if prepared is None:
            import dask

            prepared = dask.compute(self.prepare(capture))[0]
        _, K, dist = self._camera(capture)
        light_nom = capture.read("light_pos")
        R_nom, t_nom = capture.read("camera_R"), capture.read("camera_t")
        results = prepared["blocks"]
        logger.info("capture %s: measured %d poses in %d blocks", capture.url, light_nom.shape[0], len(results))
        fits = np.concatenate([r[0] for r in results])
        reasons = {pose: why for r in results for pose, why in r[1].items()}
        return self._assemble(capture, fits, reasons, K, dist, light_nom, R_nom, t_nom)

    def _detector_settings(self, sample_mm: tuple[float, float]) -> dict:
        return {"min_markers": self.min_markers, "refine_win_px": self.refine_win_px,
                "edge_refine": self.corner_refine == "edges", "texels": self.texels, "sample_mm": sample_mm,
                "max_subsamples": self.max_subsamples, "compiled": self.compiled_mapping}

    def _assemble(self, capture, fits: np.ndarray, reasons: dict[int, str], K, dist, light_nom, R_nom,
                  t_nom) -> Registration:
        """Accept or reject every measured pose (``fits``: :data:`FIT_DTYPE` records) and build the Registration."""
        sx, sy = (float(s) for s in capture.attrs["sample"]["size_mm"])
        U, V = self.texels
        texel_mm = min(sx / U, sy / V)
        poses = fits["pose"]
        why = np.array([reasons.get(int(p), "") for p in poses], object)
        over = fits["ok"] & (why == "") & (fits["rms_mm"] > self.max_rms_mm)
        for j in np.flatnonzero(over):
            why[j] = (f"registration RMS {fits['rms_mm'][j]:.3f} mm > max_rms_mm {self.max_rms_mm:g} mm "
                      f"({fits['markers'][j]} markers)")
        if self.max_pose_deg is not None:
            # Angle of R_nom^T R_measured, from its trace.
            tr = np.einsum("pji,pji->p", R_nom[poses], fits["R"])
            ang = np.degrees(np.arccos(np.clip((tr - 1) / 2, -1.0, 1.0)))
            for j in np.flatnonzero(fits["ok"] & (why == "") & (ang > self.max_pose_deg)):
                why[j] = (f"fiducial pose differs from the nominal one by {ang[j]:.1f} deg > max_pose_deg "
                          f"{self.max_pose_deg:g} (wrong manifest pose or misidentified markers?)")
        keep = fits["ok"] & (why == "")
        rejected = [{"pose": int(poses[j]), "reason": why[j],
                     **({"rms_mm": round(float(fits["rms_mm"][j]), 4)} if np.isfinite(fits["rms_mm"][j]) else {})}
                    for j in np.flatnonzero(~keep)]
        if not keep.any():
            lines = "; ".join(f"pose {r['pose']}: {r['reason']}" for r in rejected[:8])
            raise SbrdfError(f"capture {capture.url}: aruco registration rejected all {len(fits)} poses ({lines}"
                             f"{' ...' if len(rejected) > 8 else ''})")
        accepted = fits[keep]
        ids = accepted["pose"].astype(np.int64)
        if self.pose_from == "fiducials":
            R, t = accepted["R"], accepted["t"]
        else:
            R, t = R_nom[ids], t_nom[ids]
        cam_pos = camera_centre(R, t)
        light = light_nom[ids].copy()
        if self.pose_from == "fiducials" and self.correct_light:
            # [R_m|t_m] = [R_n|t_n]·[dR|dt]: the sample frame moved by (dR, dt) in the lab, the light did not.
            dR = np.einsum("pji,pjk->pik", R_nom[ids], R)  # R_n^T R_m
            dt = np.einsum("pji,pj->pi", R_nom[ids], t - t_nom[ids])
            light = np.einsum("pji,pj->pi", dR, light_nom[ids] - dt)  # dR^T (l - dt)
        rms = accepted["rms_mm"]
        reg = Registration(
            texels=(U, V), size_mm=(sx, sy), pose_ids=ids, light_pos=light, camera_pos=cam_pos,
            homography=accepted["H"].copy(), rms_mm=rms.copy(), rejected=rejected,
            extra={
                "method": "aruco",
                "K": K.tolist(), "dist": dist.tolist(), "image_size": [int(capture.attrs["camera"]["width"]),
                                                                         int(capture.attrs["camera"]["height"])],
                "homography_maps": "sample-plane mm -> undistorted pixel (apply K, dist to reach the photograph)",
                "pose_from": self.pose_from,
                "edge": self.edge, "edge_min_weight": self.edge_min_weight, "edge_margin_px": self.edge_margin_px,
                "texel_mm": texel_mm,
                "rms_mm_mean": float(rms.mean()),
                "rms_mm_max": float(rms.max()),
                "rms_texel_mean": float(rms.mean() / texel_mm),
                "reprojection_px_mean": float(accepted["reproj_px"].mean()),
                "markers_mean": float(accepted["markers"].mean()),
                "accepted": int(len(ids)), "rejected": int(len(rejected)),
            },
            per_pose={
                "camera_R": np.ascontiguousarray(R, np.float64), "camera_t": np.ascontiguousarray(t, np.float64),
                # The resampling filter (measured with the fit), so users see the effective resolution.
                "pixels_per_texel": accepted["px_per_texel"].copy(),
                "pyramid_level": accepted["level"].copy(),
                "subsamples": np.stack([accepted["n_u"], accepted["n_v"]], axis=-1),
            },
        )
        return reg

    # -- resampling (one pose per call) ---------------------------------------------------------

    def resample(self, image: np.ndarray, valid: np.ndarray, pose: int, registration: Registration):
        """One pose -> ``(V, U, 3)`` texel radiance and ``(V, U)`` validity (see the module docstring)."""
        import cv2

        reg = registration
        k = int(np.flatnonzero(reg.pose_ids == pose)[0])
        K = np.asarray(reg.extra["K"], float)
        dist = np.asarray(reg.extra["dist"], float)
        H = reg.homography[k]
        U, V = reg.texels
        sx, sy = reg.size_mm
        h, w = image.shape[:2]
        strict = self.edge == "strict"
        level = int(reg.per_pose["pyramid_level"][k])
        scale = 2.0 ** -level
        hl, wl = h, w  # the image's size at the pyramid level (cv2.pyrDown's)
        for _ in range(level):
            hl, wl = (hl + 1) // 2, (wl + 1) // 2
        compiled = self.compiled_mapping
        n_u, n_v = (int(n) for n in reg.per_pose["subsamples"][k])
        offsets = subsample_offsets(n_u, n_v)
        r = BICUBIC_RADIUS + int(math.ceil(self.edge_margin_px))

        def maps_of(ou: float, ov: float) -> tuple[np.ndarray, np.ndarray]:
            return texel_maps((U, V), (sx, sy), (ou, ov), H, K, dist, scale, compiled)

        # Every sub-sample's maps first (when they are small): their bounding box is all of the
        # photograph this pose's filter can reach, and only that region is masked, pre-blurred and
        # sampled (``_crop_window``: the same bits as the whole photograph).
        maps = [maps_of(*o) for o in offsets] if len(offsets) * U * V * 8 <= MAPS_HELD_BYTES else None
        y0, y1, x0, x1 = self._crop_window(maps, level, r, (h, w)) if maps is not None and self.crop else (0, h, 0, w)
        image = np.asarray(image[y0:y1, x0:x1], np.float32)
        finite = np.isfinite(image)
        if not finite.all():
            image = np.where(finite, image, np.float32(0))

        def square(n: int) -> np.ndarray:
            return np.ones((2 * n + 1, 2 * n + 1), np.uint8)

        invalid = (~np.asarray(valid[y0:y1, x0:x1], bool)).astype(np.uint8)
        # 1: carrier, markers, beyond the sample
        off = self._outside_sample_mask(H, K, dist, (sx, sy), image.shape[:2], (x0, y0))
        # (Masks stay one channel each: cv2.remap interpolates 2-channel images less precisely.)
        hard_f: np.ndarray | None = None
        if strict:
            # Any pixel the bicubic kernel (+ margin) touches must be valid and on the sample.
            hard_f = cv2.dilate(invalid | off, square(r)).astype(np.float32)
        else:
            # Invalid (saturated, under-exposed) pixels still invalidate every texel whose filter touches
            # them (none: the usual case, nothing to remap); the sample edge and the image border only
            # clip the filter (renormalised, see below).
            if invalid.any():
                hard_f = cv2.dilate(invalid, square(r)).astype(np.float32)
            m = int(math.ceil(self.edge_margin_px))
            usable = (1 - (cv2.dilate(off, square(m)) if m > 0 else off)).astype(np.float32)
            # Where the bicubic kernel would touch a pixel that is not usable.
            near_f: np.ndarray = cv2.dilate(off, square(r)).astype(np.float32)
            # The normalised convolution's numerator (the usable pixels' radiance) and denominator.
            numden = cv2.merge([*(cv2.multiply(c, usable) for c in cv2.split(image)), usable])

        for _ in range(level):
            image = cv2.pyrDown(image)
            if hard_f is not None:
                hard_f = cv2.pyrDown(hard_f)
            if not strict:  # normalised convolution: the pre-blur of the usable pixels only
                near_f, numden = cv2.pyrDown(near_f), cv2.pyrDown(numden)

        acc = np.zeros((V, U, 3), np.float32)
        weight = np.zeros((V, U), np.float32)  # sum over sub-samples of the filter weight on usable pixels
        badness = np.zeros((V, U), np.float32)
        for ou, ov in offsets:
            if maps is not None:
                mx, my = maps.pop(0)  # this sub-sample's (the list is in offsets' order), released as it is used
            else:
                mx, my = maps_of(ou, ov)
            # Outside the (possibly reduced) image, with room for the bicubic kernel.
            out = (mx < 1) | (my < 1) | (mx > wl - 2) | (my > hl - 2)
            if x0 or y0:  # to the window's pixels: whole pixels at this level, so exact (see _crop_window)
                mx -= np.float32(x0 >> level)
                my -= np.float32(y0 >> level)
            cubic = cv2.remap(image, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            if strict:
                assert hard_f is not None
                acc += cubic
                weight += 1.0
                np.maximum(badness, cv2.remap(hard_f, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                              borderValue=1.0), out=badness)
                badness[out] = 1.0
                continue
            if hard_f is not None:
                np.maximum(badness, cv2.remap(hard_f, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                              borderValue=0.0), out=badness)
            near = out | (cv2.remap(near_f, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                    borderValue=1.0) > 1e-6)
            # Clipped filter: bilinear interpolation of the usable pixels only, weights renormalised
            # (normalised convolution); what it reaches of the usable pixels is its weight.  Only
            # the clipped texels (the outer rings) are interpolated so.
            clipped = np.flatnonzero(near)
            reached = np.ones((V, U), np.float32)
            if clipped.size:  # (cv2.remap refuses empty maps)
                nd = cv2.remap(numden, mx.reshape(-1)[clipped, None], my.reshape(-1)[clipped, None],
                               cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0).reshape(-1, 4)
                cubic.reshape(-1, 3)[clipped] = nd[:, :3]
                reached.reshape(-1)[clipped] = nd[:, 3]
            acc += cubic
            weight += reached
        with np.errstate(divide="ignore", invalid="ignore"):
            texels = acc / weight[..., None]
        ok = badness <= 1e-6
        if not strict:
            ok &= weight >= np.float32(self.edge_min_weight * n_u * n_v) - 1e-6
            ok &= weight > 0
        # Texels facing away from the measured camera are not seen at all.
        if reg.camera_pos[k][2] <= 0:
            ok[:] = False
        for c in range(3):
            ok &= np.isfinite(texels[..., c])
        texels[~ok] = 0.0
        return texels, ok

    @staticmethod
    def _crop_window(maps, level: int, r: int, shape) -> tuple[int, int, int, int]:
        """The part ``(y0, y1, x0, x1)`` of the photograph a pose's resampling reads: the sub-samples'
        ``maps`` (pyramid level ``level``) with room for the filter, or all of it.

        Resampling a window is resampling the photograph, bit for bit, when nothing a sample point
        reaches differs: the masks are per pixel except their dilations (radius ≤ ``r``), which err only
        within ``r`` pixels of a window edge inside the photograph, and each ``cv2.pyrDown`` halves that
        band and adds at most 2 pixels; the window starts at a multiple of 2^level, so its pyramid is the
        photograph's, shifted by whole pixels (the float32 maps shift exactly: x ≥ shift ≥ 0), and a margin
        of ⌈r / 2^level⌉ + 8 level pixels past the farthest sample point keeps every bicubic support (2
        pixels) off the band.  Where the maps reach past the photograph's border, the window reaches it
        too, so samples there see the same border.  Non-finite points (the sentinel) or a window
        as large as the photograph: all of it.
        """
        h, w = shape
        f = 1 << level
        lo_x = min(float(mx.min()) for mx, _ in maps)
        lo_y = min(float(my.min()) for _, my in maps)
        if lo_x <= -1e5 or lo_y <= -1e5:  # a texel behind the camera (remap_maps' sentinel)
            return 0, h, 0, w
        hi_x = max(float(mx.max()) for mx, _ in maps)
        hi_y = max(float(my.max()) for _, my in maps)
        mgn = -(-r // f) + 8

        def span(lo: float, hi: float, n: int) -> tuple[int, int]:
            a = max(0, math.floor(lo) - mgn) * f
            b = min(n, (math.ceil(hi) + mgn + 1) * f)
            return (a, b) if b - a >= 16 * f else (0, n)

        (y0, y1), (x0, x1) = span(lo_y, hi_y, h), span(lo_x, hi_x, w)
        return y0, y1, x0, x1

    @staticmethod
    def _outside_sample_mask(H, K, dist, size_mm, shape, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
        """``(h, w)`` uint8, 1 outside the sample rectangle as seen in the photograph (distortion included);
        ``origin``: the photograph's pixel (x, y) at the mask's (0, 0) (a window, :meth:`_crop_window`)."""
        import cv2

        sx, sy = size_mm
        n = 64
        s = np.linspace(0.0, 1.0, n, endpoint=False)
        edge = np.concatenate([
            np.stack([-sx / 2 + s * sx, np.full(n, -sy / 2)], -1),
            np.stack([np.full(n, sx / 2), -sy / 2 + s * sy], -1),
            np.stack([sx / 2 - s * sx, np.full(n, sy / 2)], -1),
            np.stack([np.full(n, -sx / 2), sy / 2 - s * sy], -1),
        ])
        pix = plane_to_pixels(edge, H, K, dist)
        mask = np.ones(shape, np.uint8)
        if not np.isfinite(pix).all():
            return mask  # the sample reaches behind the camera: nothing is trusted
        pts = np.round(pix * 16).astype(np.int32).reshape(-1, 1, 2)  # 4 fractional bits
        pts -= np.array(origin, np.int32) * 16  # whole pixels: the same raster, shifted
        cv2.fillPoly(mask, [pts], 0, lineType=cv2.LINE_8, shift=4)
        return mask


def subsample_offsets(n_u: int, n_v: int) -> list[tuple[float, float]]:
    """A pose's ``n_u × n_v`` sub-sample points, in texels from each texel's centre (:func:`texel_maps`' offset),
    evenly inside the texel: what :meth:`ArucoRegistration.resample` averages."""
    return [((a + 0.5) / n_u - 0.5, (b + 0.5) / n_v - 0.5) for a in range(n_u) for b in range(n_v)]


def _texel_axes(texels_uv, size_mm, ou: float = 0.0, ov: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Sample-plane x (``U``) and y (``V``) in mm at offset (ou, ov) texels from the texel centres (the grid's axes)."""
    U, V = texels_uv
    sx, sy = size_mm
    x = (np.arange(U) + 0.5 + ou) / U * sx - sx / 2
    y = (np.arange(V) + 0.5 + ov) / V * sy - sy / 2
    return x, y


def refine_corners_by_edges(grey: np.ndarray, corners: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray | None:
    """Sub-pixel marker corners from the marker's four outer edges, in *undistorted* pixels ``(4, 2)``.

    ``cv2.aruco``'s corner refiners look at a small window around each corner,
    where the L-shaped edge carries little information (≈0.4–0.8 px errors on
    the virtual camera's markers).  Every point of the black border's outer
    edge does: along each side the 50 % crossing between the border's black
    and the quiet zone's white is found on profiles across the edge in the
    *linear* image (where a symmetric blur or the pixel's area integration
    keeps the crossing on the edge), undistorted, and a straight line is fitted
    through them; corners are the intersections of adjacent lines.  Returns
    ``None`` when an edge has too little contrast or too few crossings (the
    caller then keeps the detector's corners).  One marker of
    :func:`refine_markers_by_edges`.
    """
    return refine_markers_by_edges(grey, [corners], K, dist)[0]


def refine_markers_by_edges(grey: np.ndarray, markers, K: np.ndarray, dist: np.ndarray) -> list[np.ndarray | None]:
    """:func:`refine_corners_by_edges` for every marker of a photograph at once.

    The profiles of all edges of all markers are sampled, thresholded and
    undistorted as a few whole arrays (a Python loop per edge was most of a
    pose's measurement time).
    """
    import cv2

    if len(markers) == 0:
        return []
    c = np.asarray(markers, np.float64).reshape(-1, 4, 2)
    M = len(c)
    a, b = c, np.roll(c, -1, axis=1)  # edge k runs from corner k to corner k+1
    length = np.linalg.norm(b - a, axis=-1)  # (M, 4)
    module = length.mean(axis=1) / 6.0
    reach = np.clip(0.7 * module, 1.0, 4.0)
    n_offs = np.array([len(np.arange(-r, r + 1e-9, 0.2)) for r in reach])  # profile samples, per marker
    d = (b - a) / length[..., None]
    n = np.stack([-d[..., 1], d[..., 0]], axis=-1)
    inward = np.sum(n * ((a + b) / 2 - c.mean(axis=1, keepdims=True)), axis=-1) < 0
    n = np.where(inward[..., None], -n, n)  # outward: black border inside, white quiet zone outside
    m = np.maximum(8, length.astype(np.int64)).ravel()  # profiles per edge
    E = 4 * M
    edge = np.repeat(np.arange(E), m)  # the edge of every profile
    first = np.concatenate([[0], np.cumsum(m)[:-1]])
    i = np.arange(len(edge)) - first[edge]
    tt = np.where(i == m[edge] - 1, 0.85, 0.15 + i * ((0.85 - 0.15) / np.maximum(m[edge] - 1, 1)))
    a_, b_, n_ = a.reshape(E, 2)[edge], b.reshape(E, 2)[edge], n.reshape(E, 2)[edge]
    base = a_ + tt[:, None] * (b_ - a_)  # (R, 2) profile centres on the detected edge
    s_edge = np.zeros(len(edge))
    good = np.zeros(len(edge), bool)
    S_row = n_offs[edge // 4]
    for S in np.unique(S_row):  # markers of about the same size share a profile length
        rows = np.flatnonzero(S_row == S)
        r = reach[edge[rows] // 4]
        offs = -r[:, None] + 0.2 * np.arange(S)[None, :]  # (Rg, S) as np.arange(-reach, reach, 0.2)
        # Sample points base + offs·n, one contiguous float32 map per axis (what remap takes, uncopied).
        maps = []
        for j in range(2):
            p = offs * n_[rows, j][:, None]
            p += base[rows, j][:, None]
            maps.append(p.astype(np.float32))
        prof = cv2.remap(grey, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        q = max(1, int(S) // 5)
        black = _row_median(prof[:, :q])
        white = _row_median(prof[:, -q:])
        ok = white > black * 1.5 + 1e-12
        half = (black + white) / 2
        above = prof >= half[:, None]
        idx = np.argmax(above, axis=1)  # first index from the inside where the profile reaches half level
        ok &= (idx > 0) & above.any(axis=1)
        idx = np.clip(idx, 1, S - 1)
        k = np.arange(len(rows))
        p0, p1 = prof[k, idx - 1], prof[k, idx]
        frac = np.where(p1 > p0, (half - p0) / np.where(p1 > p0, p1 - p0, 1.0), 0.5)
        s_edge[rows] = offs[k, idx - 1] + np.clip(frac, 0, 1) * (offs[:, 1] - offs[:, 0] if S > 1 else 0.2)
        good[rows] = ok
    counts = np.bincount(edge[good], minlength=E)
    if counts.max() < 4:  # no edge has enough crossings (and undistortPoints returns None for no points)
        return [None] * M
    pts = base[good] + s_edge[good, None] * n_[good]
    und = cv2.undistortPoints(pts.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
    # Least-squares line through each edge's points: centroid and principal direction.
    e = edge[good]
    cnt = np.maximum(counts, 1)
    mu = np.stack([np.bincount(e, und[:, j], minlength=E) for j in range(2)], axis=-1) / cnt[:, None]
    du = und - mu[e]
    sxx, syy = np.bincount(e, du[:, 0] ** 2, minlength=E), np.bincount(e, du[:, 1] ** 2, minlength=E)
    sxy = np.bincount(e, du[:, 0] * du[:, 1], minlength=E)
    _, vecs = np.linalg.eigh(np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2))
    direction = vecs[..., -1].reshape(M, 4, 2)  # the largest eigenvalue's eigenvector
    mu = mu.reshape(M, 4, 2)
    # Corner k is where the lines of edges k-1 and k meet.
    p, u = np.roll(mu, 1, axis=1), np.roll(direction, 1, axis=1)
    qq, v = mu, direction
    det = -u[..., 0] * v[..., 1] + v[..., 0] * u[..., 1]
    rhs = qq - p
    with np.errstate(divide="ignore", invalid="ignore"):
        s_ = (-rhs[..., 0] * v[..., 1] + v[..., 0] * rhs[..., 1]) / det
    out = p + s_[..., None] * u
    fine = (counts.reshape(M, 4) >= 4).all(axis=1) & (np.abs(det) >= 1e-9).all(axis=1)
    return [out[j] if fine[j] else None for j in range(M)]


def _row_median(a: np.ndarray) -> np.ndarray:
    """``np.median(a, axis=1)`` of a few finite columns, the same bits, from one small sort per row (np.median's
    partition machinery cost more than the sorts at a profile's 3-8 samples)."""
    s = np.sort(a, axis=1)
    h = a.shape[1] // 2
    return s[:, h] if a.shape[1] % 2 else (s[:, h - 1] + s[:, h]) / 2


# ---------------------------------------------------------------------------
# detection + measurement of one pose (a dask task)
# ---------------------------------------------------------------------------


def _measure_pose(pose: int, images, valids, fiducials: dict, K, dist, R_nom, t_nom, settings) -> PoseFit:
    import cv2

    image = np.asarray(images[pose])  # the capture's (P, H, W, 3) zarr array: this pose only
    valid = np.asarray(valids[pose])
    centre_nom = camera_centre(R_nom, t_nom)
    if centre_nom[2] <= 0:
        return PoseFit(pose, False, f"nominal camera is behind the sample plane (camera z = {centre_nom[2]:.1f} mm in "
                                    "the manifest); the sample cannot be seen from there")
    peak = float(image.max())  # NaN or inf: a broken photograph, whose finite pixels' peak counts
    if not math.isfinite(peak):
        finite = np.isfinite(image)
        peak = float(image[finite].max()) if finite.any() else math.nan
    if not peak > 0:
        return PoseFit(pose, False, "image is black (no positive radiance): too few markers (found 0)")
    lin = luminance(image)  # the linear image the edges are refined in, and the detector's grey
    grey = tone_map(image, valid, lin)
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, fiducials["dictionary"]))
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = settings["refine_win_px"]
    params.cornerRefinementMaxIterations = 50
    params.cornerRefinementMinAccuracy = 0.005
    if hasattr(params, "relativeCornerRefinmentWinSize"):
        params.relativeCornerRefinmentWinSize = settings.get("relative_win", 0.3)
    params.cornerRefinementMethod = settings.get("method", cv2.aruco.CORNER_REFINE_SUBPIX)
    corners, ids, _ = cv2.aruco.ArucoDetector(dictionary, params).detectMarkers(grey)
    printed = {int(m["id"]): np.asarray(m["corners_mm"], float) for m in fiducials["markers"]}
    found = [] if ids is None else [(int(i), c.reshape(4, 2)) for i, c in zip(ids.ravel(), corners)]
    found = [(i, c) for i, c in found if i in printed]
    seen = {}
    for i, c in found:  # a marker id seen twice is ambiguous: drop both
        seen[i] = None if i in seen else c
    found = [(i, c) for i, c in seen.items() if c is not None]
    n_need = settings["min_markers"]
    if len(found) < n_need:
        return PoseFit(pose, False, f"too few markers: found {len(found)} of {len(printed)}, need min_markers "
                                    f"{n_need} (occluded, blurred, too dark or out of view)", markers=len(found))
    obj = np.concatenate([printed[i] for i, _ in found])
    if settings.get("edge_refine", True):
        und_list = []
        for (_, c), r in zip(found, refine_markers_by_edges(lin, [c for _, c in found], K, dist)):
            und_list.append(r if r is not None else cv2.undistortPoints(c.reshape(-1, 1, 2).astype(np.float64), K, dist,
                                                                         P=K).reshape(-1, 2))
        und = np.concatenate(und_list)
    else:
        und = cv2.undistortPoints(np.concatenate([c for _, c in found]).reshape(-1, 1, 2).astype(np.float64), K, dist,
                                  P=K).reshape(-1, 2)
    # Back to the photograph (distorted pixels) for solvePnP and the reported corners.
    nrm = cv2.undistortPoints(und.reshape(-1, 1, 2), K, np.zeros(5)).reshape(-1, 2)
    img_pts = np.stack(distort(nrm[:, 0], nrm[:, 1], K, dist), axis=-1)
    H, _ = cv2.findHomography(obj, und, 0)
    if H is None or not np.isfinite(H).all():
        return PoseFit(pose, False, f"homography fit failed on {len(found)} markers (degenerate corner layout)",
                       markers=len(found))
    H = H / H[2, 2]
    back = cv2.perspectiveTransform(und.reshape(-1, 1, 2), np.linalg.inv(H)).reshape(-1, 2)
    rms_mm = float(np.sqrt(np.mean(np.sum((back - obj) ** 2, axis=-1))))
    obj3 = np.concatenate([obj, np.zeros((len(obj), 1))], axis=1)
    ok, rvec, tvec = cv2.solvePnP(obj3, img_pts, K, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return PoseFit(pose, False, "solvePnP found no camera pose for the detected markers", markers=len(found))
    rvec, tvec = cv2.solvePnPRefineLM(obj3, img_pts, K, dist, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    t = tvec.ravel()
    proj, _ = cv2.projectPoints(obj3, rvec, tvec, K, dist)
    reproj = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img_pts) ** 2, axis=-1))))
    # Only what registration uses (packed into one FIT_DTYPE record by _measure_poses).
    fit = PoseFit(pose, True, markers=len(found), H=H, rms_mm=rms_mm, reproj_px=reproj, R=R, t=t)
    c = camera_centre(R, t)
    if c[2] <= 0:
        fit.ok, fit.reason = False, f"fiducials put the camera behind the sample plane (z = {c[2]:.1f} mm)"
    return fit


def _measure_poses(lo: int, hi: int, images, valids, fiducials: dict, K, dist, R_nom, t_nom,
                   settings) -> tuple[np.ndarray, dict]:
    """A dask task: poses ``lo:hi`` -> (:data:`FIT_DTYPE` records, ``{pose: reason}`` for failures).

    Each accepted pose's resampling filter (:func:`footprint`) is measured here too,
    while its homography is at hand, so the runner never loops over poses.
    """
    out = np.zeros(hi - lo, FIT_DTYPE)
    reasons = {}
    for j, pose in enumerate(range(lo, hi)):
        f = _measure_pose(pose, images, valids, fiducials, K, dist, R_nom[pose], t_nom[pose], settings)
        rec = out[j]
        rec["pose"], rec["ok"], rec["markers"] = pose, f.ok, f.markers
        rec["rms_mm"], rec["reproj_px"] = f.rms_mm, f.reproj_px
        if not f.ok:
            reasons[pose] = f.reason
        if f.H is None or f.R is None:
            rec["H"] = rec["R"] = np.nan
            continue
        rec["H"], rec["R"], rec["t"] = f.H, f.R, f.t
        if f.ok:
            rec["level"], rec["n_u"], rec["n_v"], rec["px_per_texel"] = footprint(
                f.H, K, dist, settings["texels"], settings["sample_mm"], settings["max_subsamples"],
                settings.get("compiled", False))
    return out, reasons


def footprint(H: np.ndarray, K, dist, texels: tuple[int, int], size_mm, max_subsamples: int,
              compiled: bool = False) -> tuple[int, int, int, float]:
    """A pose's resampling filter from the mapping's Jacobian: (pyramid level, sub-samples along u and v, pixels per texel).

    The Jacobian's columns are the pixels moved per texel step along u and v; the
    largest, over the sample, sets how many bicubic sub-samples a texel needs, and
    octaves of pre-blur keep that at most ``max_subsamples`` per axis.

    The texel centres' pixels come from OpenCV's float32 map (:func:`texel_maps`, a fifth of the NumPy
    mapping's time) when the choice it gives cannot be the float64 grid's: every length is within a few
    float32 ulps of the pixel coordinates of the float64 one, so the choice is kept when it is the same at
    both ends of that interval, and the float64 grid decides otherwise (a length at a sub-sample count's
    boundary).  Pixels per texel, a figure for users, then agree to about 1e-5.
    """
    K, dist = np.asarray(K, float), np.asarray(dist, float)
    H = np.asarray(H, np.float64)
    U, V = texels
    xs, ys = _texel_axes((U, V), size_mm)
    if not compiled and _opencv_maps_apply(xs, ys, H, K, dist):
        px32, py32 = _opencv_texel_maps((U, V), size_mm, (0.0, 0.0), H, K, dist, 1.0)
        farthest = max(float(np.abs(px32).max()), float(np.abs(py32).max()))
        # (Pixels beyond ±1e5, or remap_maps' sentinel, are no footprint to measure in float32: float64 decides.)
        if farthest < 1e5:
            lu, lv, px_per_texel = _jacobian_lengths(px32, py32)
            # |map - float64 grid| <= 1 ulp per coordinate, so a central difference is off by <= 1 ulp and a length
            # by <= sqrt(2) ulps, plus float32 rounding in the length itself: 4 ulps of the largest coordinate.
            tol = 4.0 * float(np.spacing(np.float32(farthest)))
            choice = _filter_choice(lu, lv, max_subsamples)
            if all(_filter_choice(lu + a, lv + b, max_subsamples) == choice for a in (-tol, tol) for b in (-tol, tol)):
                return (*choice, px_per_texel)
    if compiled:
        pix = grid_to_pixels(xs, ys, H, K, dist, True)  # (V, U, 2) at the texel centres
        px, py = pix[..., 0], pix[..., 1]
    else:
        px, py = _grid_xy(xs, ys, H, K, dist)
    lu, lv, px_per_texel = _jacobian_lengths(px, py)
    return (*_filter_choice(lu, lv, max_subsamples), px_per_texel)


def _jacobian_lengths(px: np.ndarray, py: np.ndarray) -> tuple[float, float, float]:
    """The texel centres' pixels ``(V, U)`` -> the largest Jacobian column lengths along u and v and
    sqrt(median(du·dv)) (pixels per texel), over the texels with finite columns."""
    V, U = px.shape

    def length(axis: int) -> np.ndarray:  # np.linalg.norm(np.gradient(pix, axis=axis), axis=-1), per component
        gx, gy = np.gradient(px, axis=axis), np.gradient(py, axis=axis)
        gx *= gx
        gy *= gy
        gx += gy
        return np.sqrt(gx, out=gx)

    du = length(1) if U > 1 else np.ones((V, U), px.dtype)
    dv = length(0) if V > 1 else np.ones((V, U), px.dtype)
    fin = np.isfinite(du) & np.isfinite(dv)
    every = bool(fin.all())  # the usual case: no masked copies
    if every:
        du_f, dv_f = du.ravel(), dv.ravel()
    else:
        du_f, dv_f = du[fin], dv[fin]
    lu = float(np.max(du_f)) if du_f.size else 1.0
    lv = float(np.max(dv_f)) if dv_f.size else 1.0
    # (du·dv is a fresh array: the median may partition it in place, the same order statistics.)
    px_per_texel = float(np.sqrt(np.median(du_f * dv_f, overwrite_input=True))) if du_f.size else 0.0
    return lu, lv, px_per_texel


def _filter_choice(lu: float, lv: float, max_subsamples: int) -> tuple[int, int, int]:
    """(pyramid level, n_u, n_v) for the largest Jacobian column lengths ``lu``, ``lv`` (pixels per texel step)."""
    level = max(0, math.ceil(math.log2(max(lu, lv, 1e-9) / max_subsamples))) if max(lu, lv) > max_subsamples else 0
    scale = 2.0 ** -level
    n_u = max(1, math.ceil(lu * scale - 1e-6))
    n_v = max(1, math.ceil(lv * scale - 1e-6))
    return level, n_u, n_v
