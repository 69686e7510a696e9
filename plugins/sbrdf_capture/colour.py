"""Colour calibration: camera RGB -> CIE XYZ -> the linear working RGB space.

A camera's RGB is its own colour space.  Seed 000 §3.4.2: photograph a
colour checker in HDR, average each patch, and solve a least-squares 3×3
matrix to the patches' measured XYZ; then convert XYZ to the working space.
The working space here is **linear Rec. 709 / sRGB primaries with a D65
white** (the thesis used Sony Trinitron primaries).  Values outside [0, 1]
(out of gamut, HDR) are kept: nothing is clamped before fitting.

No spectroradiometer is at hand, so :func:`colour_checker_xyz` synthesises the
24 ColorChecker Classic patches from commonly published approximate 8-bit sRGB
values: exact enough to be a ground truth for tests and simulations, not a
reference measurement.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError

#: XYZ (D65) -> linear sRGB / Rec. 709 (IEC 61966-2-1).
XYZ_TO_LINEAR_SRGB = np.array([
    [3.2404542, -1.5371385, -0.4985314],
    [-0.9692660, 1.8760108, 0.0415560],
    [0.0556434, -0.2040259, 1.0572252],
])
LINEAR_SRGB_TO_XYZ = np.linalg.inv(XYZ_TO_LINEAR_SRGB)

#: Luminance weights of the working space (the Y row of LINEAR_SRGB_TO_XYZ).
LUMINANCE_WEIGHTS = LINEAR_SRGB_TO_XYZ[1]

#: ColorChecker Classic, approximate 8-bit sRGB, row by row (dark skin ... black).
COLOR_CHECKER_SRGB8 = np.array([
    [115, 82, 68], [194, 150, 130], [98, 122, 157], [87, 108, 67], [133, 128, 177], [103, 189, 170],
    [214, 126, 44], [80, 91, 166], [193, 90, 99], [94, 60, 108], [157, 188, 64], [224, 163, 46],
    [56, 61, 150], [70, 148, 73], [175, 54, 60], [231, 199, 31], [187, 86, 149], [8, 133, 161],
    [243, 243, 242], [200, 200, 200], [160, 160, 160], [122, 122, 121], [85, 85, 85], [52, 52, 52],
], dtype=np.float64)


class ColourError(SbrdfError):
    """A colour calibration cannot be computed."""


def srgb8_to_linear(values: np.ndarray) -> np.ndarray:
    s = np.asarray(values, np.float64) / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def colour_checker_xyz() -> np.ndarray:
    """``(24, 3)`` XYZ of the synthetic checker patches (white patch Y ≈ 0.9)."""
    return srgb8_to_linear(COLOR_CHECKER_SRGB8) @ LINEAR_SRGB_TO_XYZ.T


def fit_camera_to_xyz(camera_rgb: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Least-squares ``M`` with ``xyz ≈ M @ rgb`` for every patch (``(N, 3)`` each, N ≥ 3).

    Returns ``M (3, 3)``.  Patches with non-finite values are dropped; fewer
    than 3 usable, or a rank-deficient set, is an error.
    """
    rgb = np.asarray(camera_rgb, np.float64).reshape(-1, 3)
    target = np.asarray(xyz, np.float64).reshape(-1, 3)
    if rgb.shape != target.shape:
        raise ColourError(f"camera patches {rgb.shape} and XYZ patches {target.shape} differ in number")
    ok = np.isfinite(rgb).all(axis=1) & np.isfinite(target).all(axis=1)
    if ok.sum() < 3:
        raise ColourError(f"need at least 3 usable patches, got {int(ok.sum())}")
    solution, _, rank, _ = np.linalg.lstsq(rgb[ok], target[ok], rcond=None)
    if rank < 3:
        raise ColourError("the patches' camera RGB values are linearly dependent (rank < 3); use a colour checker, not greys")
    return solution.T


def camera_to_working(camera_to_xyz: np.ndarray) -> np.ndarray:
    """The one 3×3 matrix camera RGB -> linear sRGB working space."""
    return XYZ_TO_LINEAR_SRGB @ np.asarray(camera_to_xyz, np.float64)


def apply_matrix(image: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``(..., 3) @ Mᵀ`` in float32, no clamping."""
    return np.einsum("...c,dc->...d", np.asarray(image, np.float32), np.asarray(matrix, np.float32))
