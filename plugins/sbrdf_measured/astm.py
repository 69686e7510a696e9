"""ASTM E1392 goniometric BRDF text files, as published by the Cornell reflectance measurements.

Layout (the one read by ALTA's ``data_astm`` plugin and libbsdf's ``AstmReader``, the two public readers of
the Cornell database's ``.astm`` files):

- header lines ``KEY value...`` (``NAME``, ``NUM_POINTS n``, ...), ending with the line
  ``VARS theta_i,phi_i,theta_s,phi_s,<channels>``: the column names, comma-separated;
- one sample per line, comma-separated numbers in the ``VARS`` order: the incident and scattered directions'
  polar and azimuthal angles in **radians** (θ from the normal, φ from the +x tangent; negative φ allowed)
  and the BRDF value of each channel in sr⁻¹;
- channels: ``R,G,B`` (linear RGB), ``X,Y,Z`` (CIE XYZ, converted here to linear sRGB with the IEC 61966-2-1
  D65 matrix), or one column (luminance or one wavelength, repeated into R, G, B).  Spectral files (several
  ``<λ>nm`` columns) are refused with a message: convert them to RGB first.

``NUM_POINTS``, when given, must equal the number of data lines.  Blank lines are skipped.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sbrdf_core import input_files

ANGLES = ("theta_i", "phi_i", "theta_s", "phi_s")
XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]])


class AstmError(ValueError):
    """A malformed ASTM file; the message names the file and line."""


@dataclass
class AstmTable:
    """Samples of an ASTM file: directions ``(N, 3)`` and RGB f_r ``(N, 3)`` sr⁻¹."""

    wi: np.ndarray
    wo: np.ndarray
    f_r: np.ndarray
    channels: tuple[str, ...]
    header: dict = field(default_factory=dict)
    source: str = "<memory>"

    def __len__(self) -> int:
        return len(self.f_r)


def direction(theta, phi) -> np.ndarray:
    theta, phi = np.asarray(theta, float), np.asarray(phi, float)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def read_astm(path: str | os.PathLike) -> AstmTable:
    path = Path(path)
    try:
        lines = input_files.read_bytes(path, text=True).decode("utf-8", errors="strict").splitlines()
    except FileNotFoundError:
        raise AstmError(f"{path}: no such ASTM file") from None
    except OSError as e:  # a device, FIFO or directory, or over the text limit
        raise AstmError(f"{path}: cannot read the ASTM file: {e.strerror}") from None
    header: dict[str, str] = {}
    names = None
    start = 0
    for n, line in enumerate(lines):
        text = line.strip()
        if not text:
            continue
        key, _, rest = text.partition(" ")
        if key == "VARS" or key.startswith("VARS,"):
            names = [v.strip() for v in (rest if key == "VARS" else text[4:]).strip().split(",") if v.strip()]
            start = n + 1
            break
        header[key] = rest.strip()
    if names is None:
        raise AstmError(f"{path}: no VARS line (the ASTM header ends with 'VARS theta_i,phi_i,theta_s,phi_s,...')")
    if tuple(names[:4]) != ANGLES or len(names) < 5:
        raise AstmError(f"{path}:{start}: VARS must start with {','.join(ANGLES)} and name at least one channel, "
                        f"got {','.join(names)}")
    channels = tuple(names[4:])
    if len(channels) > 1 and channels not in (("R", "G", "B"), ("X", "Y", "Z")):
        raise AstmError(f"{path}:{start}: channels {','.join(channels)} are not supported (R,G,B, X,Y,Z or one "
                        "channel; convert spectral files to RGB first)")
    rows = []
    for n in range(start, len(lines)):
        text = lines[n].strip()
        if not text:
            continue
        parts = text.replace(" ", "").split(",")
        if len(parts) != len(names):
            raise AstmError(f"{path}:{n + 1}: {len(parts)} values, the VARS line names {len(names)}")
        try:
            rows.append([float(p) for p in parts])
        except ValueError:
            raise AstmError(f"{path}:{n + 1}: not a number in {text!r}") from None
    if not rows:
        raise AstmError(f"{path}: no data lines after VARS")
    data = np.asarray(rows, np.float64)
    if "NUM_POINTS" in header:
        try:
            expected = int(header["NUM_POINTS"].split()[0])
        except (ValueError, IndexError):
            raise AstmError(f"{path}: NUM_POINTS {header['NUM_POINTS']!r} is not an integer") from None
        if expected != len(data):
            raise AstmError(f"{path}: NUM_POINTS says {expected} samples, the file has {len(data)}")
    values = data[:, 4:]
    if channels == ("X", "Y", "Z"):
        values = values @ XYZ_TO_SRGB.T
    elif len(channels) == 1:
        values = np.repeat(values, 3, axis=1)
    return AstmTable(direction(data[:, 0], data[:, 1]), direction(data[:, 2], data[:, 3]), values, channels, header,
                     str(path))


def write_astm(path: str | os.PathLike, theta_i, phi_i, theta_s, phi_s, f_r, name: str = "sbrdf") -> None:
    """Write RGB samples (angles in radians, ``f_r (N, 3)``) as an ASTM file with R,G,B channels."""
    f_r = np.asarray(f_r, float).reshape(-1, 3)
    cols = np.column_stack([np.ravel(theta_i), np.ravel(phi_i), np.ravel(theta_s), np.ravel(phi_s), f_r])
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"NAME {name}\nNUM_POINTS {len(cols)}\nVARS {','.join(ANGLES)},R,G,B\n")
        for row in cols:
            f.write(",".join(f"{v:.9g}" for v in row) + "\n")


__all__ = ["AstmError", "AstmTable", "read_astm", "write_astm"]
