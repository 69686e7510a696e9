"""The compiled Reflectance kernel gives the NumPy kernel's bits, texel-major.

``reflectance_tile`` (one numba loop, the node's kernel on large scans) must store exactly what
``reflectance_block`` (the NumPy reference, and the node's kernel on small scans) gives, transposed:
a scan's artifact may not depend on its size.  Hard cases: non-finite and masked radiance, grazing
and below-horizon lights, a light on a texel centre (distance 0), blocks that are part of the grid.
"""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.nodes.reflectance import reflectance_block, reflectance_tile


def both(rad, valid, lp, cp, texels, size, intensity, min_cos, rows, cols):
    a = reflectance_block(rad, valid, lp, cp, texels, size, intensity, min_cos, rows, cols).transpose(1, 2, 0, 3)
    b = reflectance_tile(rad, valid, lp, cp, texels, size, intensity, min_cos, rows, cols)
    return a, b


@pytest.mark.parametrize("seed", range(12))
def test_compiled_kernel_matches_numpy_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    P, V, U = (int(n) for n in rng.integers(1, 24, 3))
    texels = (U + int(rng.integers(0, 20)), V + int(rng.integers(0, 20)))
    size = (float(rng.uniform(1, 200)), float(rng.uniform(1, 200)))
    v0, u0 = int(rng.integers(0, texels[1] - V + 1)), int(rng.integers(0, texels[0] - U + 1))
    rad = rng.lognormal(0, 3, (P, V, U, 3)).astype(np.float32)
    rad[rng.random(rad.shape) < 0.02] = np.inf
    rad[rng.random(rad.shape) < 0.02] = np.nan
    rad[rng.random(rad.shape) < 0.01] = np.float32(3e38)  # finite, but f_r overflows
    valid = rng.random((P, V, U)) < 0.9
    lp = rng.normal(0, 300, (P, 3))
    lp[:, 2] = np.abs(lp[:, 2]) * rng.choice([1.0, -1.0, 0.01], P)  # above, below, grazing
    cp = rng.normal(0, 300, (P, 3))
    cp[:, 2] = np.abs(cp[:, 2]) * rng.choice([1.0, 0.01], P)
    a, b = both(rad, valid, lp, cp, texels, size, float(rng.uniform(1, 1e6)), float(rng.uniform(0, 0.5)),
                (v0, v0 + V), (u0, u0 + U))
    assert a.dtype == b.dtype == np.float32 and a.shape == b.shape
    assert a.tobytes() == b.tobytes()


def test_a_light_on_a_texel_centre():
    rad = np.ones((2, 3, 3, 3), np.float32)
    lp = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 100.0]])  # the centre texel of a 3x3 grid is at the origin
    a, b = both(rad, np.ones((2, 3, 3), bool), lp, lp[::-1].copy(), (3, 3), (3.0, 3.0), 1.0, 0.0, (0, 3), (0, 3))
    assert a.tobytes() == b.tobytes()


def test_a_sample_beyond_float32_is_invalid_not_inf():
    rad = np.full((1, 1, 1, 3), 3e38, np.float32)
    lp = np.array([[0.0, 0.0, 1000.0]])  # r² / (I cos θ) = 1e6: f_r is finite in float64 only
    for out in both(rad, np.ones((1, 1, 1), bool), lp, lp, (1, 1), (1.0, 1.0), 1.0, 0.0, (0, 1), (0, 1)):
        assert out.tolist() == [[[[0.0, 0.0, 0.0, 0.0]]]]
