"""A small procedural HDR environment (lat-long), for the example scene, tests and the benchmark.

Sky gradient over a darker ground, a bright "sun" and two softer lamps, so
that glossy lobes of every width have something to blur.  Regenerate the
committed map with ``python -m sbrdf_envmap.procedural scenes/envmap_sky.exr``.
"""

from __future__ import annotations

import sys

import numpy as np


def sky(width: int = 64, height: int = 32) -> np.ndarray:
    """``(height, width, 3)`` float32 radiance; row 0 at the zenith, u = φ/2π (see :mod:`.cubemap`)."""
    theta = (np.arange(height) + 0.5) / height * np.pi
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    up = np.clip(d[..., 2], -1, 1)
    sky_col = np.array([0.35, 0.55, 1.0]) * (0.4 + 0.6 * np.clip(up, 0, 1))[..., None]
    ground = np.array([0.25, 0.2, 0.15]) * (0.5 + 0.5 * (np.sin(6 * ph) * np.sin(6 * th) > 0))[..., None]
    img = np.where((up >= 0)[..., None], sky_col, ground)
    for direction, colour, width_deg in (((0.5, -0.3, 0.8), (40.0, 36.0, 30.0), 6.0),
                                         ((-0.7, 0.6, 0.35), (4.0, 5.0, 8.0), 15.0),
                                         ((0.2, 0.9, 0.1), (6.0, 3.0, 1.5), 10.0)):
        a = np.asarray(direction) / np.linalg.norm(direction)
        ang = np.arccos(np.clip(d @ a, -1, 1))
        img = img + np.asarray(colour) * np.exp(-0.5 * (ang / np.radians(width_deg)) ** 2)[..., None]
    return img.astype(np.float32)


def main(argv=None) -> None:
    from sbrdf_core.io import write_exr

    argv = sys.argv[1:] if argv is None else argv
    out = argv[0] if argv else "envmap_sky.exr"
    write_exr(out, sky())
    print(out)


if __name__ == "__main__":
    main()
