"""Parameterizations of seed 001 §5: bijective on the hemisphere pairs, coordinates in range, and the h ≈ n singularity."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core.brdf_checks import hemisphere_directions
from sbrdf_core.registry import Registry

REGISTRY = Registry()
NAMES = ["standard", "elevation-azimuth", "rusinkiewicz", "gram-schmidt"]
CASES = [(n, m) for n in NAMES for m in ("xy", "parabolic") if not (n == "elevation-azimuth" and m == "parabolic")]


def param(name, map_="xy"):
    return REGISTRY.create("parameterization", name, {"map": map_})


def sph(theta, phi):
    t, p = np.radians(theta), np.radians(phi)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def test_all_four_are_registered_plugins():
    assert set(NAMES) <= set(REGISTRY.names("parameterization"))


@pytest.mark.parametrize("name,map_", CASES)
@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31), grazing=st.booleans())
def test_coords_in_unit_square_and_directions_invert_them(name, map_, seed, grazing):
    rng = np.random.default_rng(seed)
    wi, wo = hemisphere_directions(rng, (400,)), hemisphere_directions(rng, (400,))
    keep = (wi[:, 2] > 0.01) & (wo[:, 2] > 0.01)  # the maps' rim: 0.08 degrees above the horizon
    wi, wo = wi[keep][:200], wo[keep][:200]
    if grazing:  # within 0.5 degrees of the horizon (inside the map's rim)
        for w in (wi, wo):
            w[:, 2] = rng.uniform(0.01, 0.0087 + 0.01, 200)
            w[:, :2] *= (np.sqrt(1 - w[:, 2] ** 2) / np.linalg.norm(w[:, :2], axis=1))[:, None]
    P = param(name, map_)
    x, y = P.coords(wi, wo)
    assert np.isfinite(x).all() and np.isfinite(y).all()
    assert (x >= 0).all() and (x <= 1).all() and (y >= 0).all() and (y <= 1).all()
    wi2, wo2 = P.directions(x, y)
    np.testing.assert_allclose(wi2, wi, atol=1e-9)
    np.testing.assert_allclose(wo2, wo, atol=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_every_texel_centre_maps_to_unit_directions(name):
    from sbrdf_separable.factors import cell_centres

    c = cell_centres(16)
    wi, wo = param(name).directions(c[:, None], c[None])
    assert wi.shape == wo.shape == (256, 256, 3)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=-1), 1.0, atol=1e-12)


def test_gram_schmidt_h_coordinates_are_the_xy_hemisphere_map_of_h():
    """Eq 6 read with s (not s'): h_u = (h·t + 1)/2, h_v = (h·s + 1)/2; d_u, d_v against t', s'."""
    wi, wo = sph(np.array([30.0]), np.array([10.0])), sph(np.array([50.0]), np.array([200.0]))
    h = (wi + wo) / np.linalg.norm(wi + wo)
    x, y = param("gram-schmidt").coords(wi, wo)
    np.testing.assert_allclose(x[0], (h[0, :2] + 1) / 2)
    tp = np.array([1.0, 0, 0]) - h[0, 0] * h[0]
    tp /= np.linalg.norm(tp)
    sp = np.cross(h[0], tp)
    np.testing.assert_allclose(y[0], [(wi[0] @ tp + 1) / 2, (wi[0] @ sp + 1) / 2])


def test_singularity_at_h_equals_n_rusinkiewicz_jumps_gram_schmidt_does_not():
    """§5.1: near the specular configuration (h ≈ n) a tiny change of the directions swings Rusinkiewicz's
    difference coordinates across the map, while Gram–Schmidt's move by as little as the directions did."""
    rng = np.random.default_rng(0)
    theta = 40.0
    base_i, base_o = sph(theta, 0.0), sph(theta, 180.0)  # mirror pair: h = n exactly
    jumps = {}
    for name in ("rusinkiewicz", "gram-schmidt"):
        P = param(name)
        x0, y0 = P.coords(base_i[None], base_o[None])
        assert np.isfinite(x0).all() and np.isfinite(y0).all()  # exactly at the singularity: defined, not NaN
        np.testing.assert_allclose(x0, 0.5, atol=1e-12)
        worst = 0.0
        for eps in (1e-3, 1e-6, 1e-9):
            d = rng.normal(size=(64, 3)) * eps
            wi = base_i + d
            wi /= np.linalg.norm(wi, axis=1, keepdims=True)
            _, y = P.coords(wi, np.repeat(base_o[None], 64, 0))
            worst = max(worst, np.abs(y - y0).max() / eps)
        jumps[name] = worst
    assert jumps["gram-schmidt"] < 10.0  # Lipschitz: coordinates move like the directions
    assert jumps["rusinkiewicz"] > 1e6  # an O(1) jump for an O(1e-9) perturbation


@pytest.mark.parametrize("name", ["rusinkiewicz", "gram-schmidt"])
def test_half_difference_coordinates_are_finite_at_degenerate_pairs(name):
    """wi = wo at the normal, retro-reflection at grazing, and wi = −wo (h undefined): finite, in range."""
    wi = np.array([[0, 0, 1.0], sph(89.999, 0.0), sph(60.0, 0.0)])
    wo = np.array([[0, 0, 1.0], sph(89.999, 0.0), sph(60.0, 180.0)])
    wo[2] = -wi[2]  # opposite: below the horizon, only guarded
    x, y = param(name).coords(wi, wo)
    assert np.isfinite(x).all() and np.isfinite(y).all()
