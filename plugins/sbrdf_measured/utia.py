"""UTIA BRDF database binary files (``.bin``): anisotropic RGB BRDFs on a fixed 6 × 48 × 6 × 48 grid.

Layout (Filip & Vávra, "Template-based sampling of anisotropic BRDFs", PG 2014; as read by Filip's
``TBDRF.cpp``, ALTA's ``data_utia`` plugin and Sztrajman's ``brdf_read.py``, the public readers of the
database's ``.bin`` files):

- raw little-endian float64, no header, 3 × 6 × 48 × 6 × 48 values = 1 990 656 bytes;
- C order ``[channel][theta_i][phi_i][theta_v][phi_v]``: channel R, G, B (linear sRGB, D65); θ_i, θ_v =
  0°, 15°, …, 75° from the normal; φ_i, φ_v = 0°, 7.5°, …, 352.5° from the +x tangent;
- values are the BRDF in sr⁻¹ as measured (small negative values from noise occur and are kept).

Every grid node becomes one sample (82 944 direction pairs, those at θ = 0 repeated over φ, as measured).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .astm import AstmTable, direction

THETA_STEP_DEG, PHI_STEP_DEG = 15.0, 7.5
#: ``(channels, theta_i, phi_i, theta_v, phi_v)`` of every file.
SHAPE = (3, 6, 48, 6, 48)
FILE_BYTES = int(np.prod(SHAPE)) * 8


class UtiaError(ValueError):
    """A file that is not a UTIA BRDF ``.bin``; the message names the file."""


def grid_angles() -> tuple[np.ndarray, np.ndarray]:
    """``(theta, phi)`` of the grid nodes in radians: 6 polar and 48 azimuthal angles."""
    return (np.radians(THETA_STEP_DEG * np.arange(SHAPE[1])), np.radians(PHI_STEP_DEG * np.arange(SHAPE[2])))


def grid_directions() -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)``, ``(82944, 3)`` each, in the file's order (θ_i, φ_i, θ_v, φ_v; φ_v fastest)."""
    theta, phi = grid_angles()
    ti, pi, tv, pv = np.meshgrid(theta, phi, theta, phi, indexing="ij")
    return direction(ti.ravel(), pi.ravel()), direction(tv.ravel(), pv.ravel())


def read_utia(path: str | os.PathLike) -> AstmTable:
    """The file's samples as a direction-pair table (the same shape as an ASTM file's)."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise UtiaError(f"{path}: no such UTIA BRDF file") from None
    if size != FILE_BYTES:
        raise UtiaError(f"{path}: {size} bytes; a UTIA BRDF .bin is {FILE_BYTES} bytes "
                        f"(float64 {'x'.join(map(str, SHAPE))}: RGB x theta_i x phi_i x theta_v x phi_v)")
    from sbrdf_core.input_files import read_bytes

    try:
        raw = read_bytes(path)  # a regular file only: st_size of a FIFO or device says nothing
    except OSError as e:
        raise UtiaError(f"{path}: cannot read the UTIA BRDF file: {e.strerror}") from None
    if len(raw) != FILE_BYTES:
        raise UtiaError(f"{path}: {len(raw)} bytes read; a UTIA BRDF .bin is {FILE_BYTES} bytes")
    data = np.frombuffer(raw, dtype="<f8").reshape(SHAPE)
    wi, wo = grid_directions()
    return AstmTable(wi, wo, data.reshape(3, -1).T.copy(), ("R", "G", "B"), {"format": "utia"}, str(path))


def write_utia(path: str | os.PathLike, f_r: np.ndarray) -> None:
    """Write ``f_r`` of shape ``(6, 48, 6, 48, 3)`` (or ``(82944, 3)`` in :func:`grid_directions` order)."""
    f = np.asarray(f_r, np.float64).reshape(-1, 3)
    if f.shape[0] != int(np.prod(SHAPE[1:])):
        raise ValueError(f"write_utia: {f.shape[0]} samples, the grid has {int(np.prod(SHAPE[1:]))}")
    np.ascontiguousarray(f.T).astype("<f8").tofile(path)


__all__ = ["FILE_BYTES", "SHAPE", "UtiaError", "grid_angles", "grid_directions", "read_utia", "write_utia"]
