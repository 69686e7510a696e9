"""Shading maps (Kautz et al. 2003): linearization (Eq 1), power compression (Eq 4), lookups (Eq 2-3, Fig 6)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from sbrdf_core.registry import default_registry
from sbrdf_lib.mesostructure import Mesostructure, procedural
from sbrdf_shading.arc import render_arc_image
from sbrdf_shading.compress import evaluate_power, fit_power
from sbrdf_shading.linearize import interpolation_weights, linearize
from sbrdf_shading.shade import VARIANTS, ShadingData, angle_table, bilinear, lookup, r_value, shade, shade_environment

THETA = (15.0, 25.0, 35.0, 45.0, 55.0, 65.0, 75.0, 85.0)


def model(name, **cfg):
    return default_registry().create("brdf-model", name, cfg)


def arc_stack(meso, texels, size_mm, shadowing=False, theta=THETA, distance=1e9):
    """Light-arc images of a height field turned into BRDF·cos for a unit light (distance² / I = 1)."""
    imgs = []
    for t in np.radians(theta):
        light = distance * np.array([np.sin(t), 0.0, np.cos(t)])
        imgs.append(render_arc_image(meso, light, distance**2, texels, size_mm, shadowing))
    return np.stack(imgs).astype(np.float64)


def bumpy(texels=(32, 24), size_mm=(8.0, 6.0), amplitude=0.3, albedo=0.6):
    h = procedural({"procedural": "bumps", "amplitude_mm": amplitude, "period_mm": 2.0, "seed": 4}, texels, size_mm, "h")
    return Mesostructure(h, albedo, size_mm)


def hemisphere(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# -- linearization (Eq 1) ---------------------------------------------------------------------------------------


def test_01_slice_zero_is_black_and_averages_rise_linearly():
    meso = bumpy()
    imgs = arc_stack(meso, (32, 24), (8.0, 6.0), shadowing=True)
    slices, r, a = linearize(imgs, 8)
    assert slices.shape == (8, 24, 32, 3)
    assert np.all(slices[0] == 0.0)
    np.testing.assert_allclose(slices.mean(axis=(1, 2, 3)), r, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.diff(r), r[-1] / 7, rtol=1e-12)
    assert r[-1] == pytest.approx(a.max()) and np.argmax(a) == 0  # the light nearest the normal is brightest
    np.testing.assert_allclose(slices[-1], imgs[0])                 # the brightest slice is that image


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(st.floats(0.0, 10.0), st.just(float("nan"))), min_size=1, max_size=12), st.integers(2, 16))
def test_02_weights_interpolate_any_averages(averages, N):
    """Any averages (zero, NaN, repeated, unsorted): finite weights, each slice's average is r_i exactly."""
    a = np.array(averages)
    W = interpolation_weights(a, N)
    assert W.shape == (N, len(a)) and np.isfinite(W).all() and (W >= 0).all()
    assert np.all(W.sum(axis=1) <= 1 + 1e-12) and np.all(W[0] == 0)
    good = np.isfinite(a) & (a > 0)
    if good.any():
        r = np.arange(N) * a[good].max() / (N - 1)
        np.testing.assert_allclose(W[:, good] @ a[good], r, rtol=1e-9, atol=1e-12)
    else:
        assert not W.any()


def test_03_invalid_samples_are_filled_not_propagated():
    rng = np.random.default_rng(0)
    imgs = rng.uniform(0.1, 1.0, (5, 6, 7, 3))
    valid = rng.uniform(size=(5, 6, 7)) > 0.2
    imgs[~valid] = np.nan
    slices, r, a = linearize(imgs, 4, valid)
    assert np.isfinite(slices).all() and np.isfinite(a).all()


# -- compression (Eq 4) --------------------------------------------------------------------------------------------


def test_04_power_law_data_compresses_exactly():
    rng = np.random.default_rng(1)
    V, U = 16, 12
    k = rng.uniform(0.05, 1.0, (V, U, 3))
    K = np.round(rng.uniform(0.3, 6.0, (V, U, 3)), 2)              # on the fine grid (0.05 + 0.01 j)
    x = np.arange(8) / 7
    data = k[None] * x[:, None, None, None] ** K[None]
    k_fit, K_fit, err = fit_power(data)
    np.testing.assert_allclose(k_fit, k, rtol=1e-12)
    np.testing.assert_allclose(K_fit, K, atol=1e-9)
    assert np.sqrt(err.max() / 8) < 1e-9


@settings(max_examples=60, deadline=None)
@given(K=st.floats(0.06, 11.9), k=st.floats(1e-3, 100.0), N=st.integers(3, 16))
@example(K=1.3549929, k=1.0, N=3)
def test_05_power_law_exponent_is_the_better_of_its_fine_step_neighbours(K, k, N):
    """K lands between two fine-grid exponents; the fit is whichever fits the slices better.

    Not always the nearer one: x^K is convex in K, so near a midpoint the farther
    neighbour can have the smaller squared error (K = 1.35499, N = 3 fits 1.36).
    """
    x = np.arange(N) / (N - 1)
    s = k * x**K
    k_fit, K_fit, err = fit_power(s[:, None], fine_step=0.01)
    below = 0.05 + 0.01 * np.floor((K - 0.05) / 0.01 + 1e-9)
    neighbours = np.array([below, below + 0.01])
    sq = ((s[None, :] - k * x[None, :] ** neighbours[:, None]) ** 2).sum(axis=1)
    assert K_fit[0] == pytest.approx(neighbours[np.argmin(sq)], abs=1e-9) or np.ptp(sq) <= 1e-12 * sq.max()
    assert abs(K_fit[0] - K) <= 0.01 + 1e-9 and k_fit[0] == pytest.approx(k)
    assert err[0] == pytest.approx(sq.min(), rel=1e-9, abs=1e-24 * (s * s).sum())


def test_06_compression_handles_black_nan_and_huge_values():
    data = np.zeros((8, 3))
    data[:, 1] = np.nan
    data[:, 2] = np.linspace(0, 1e30, 8)
    k, K, err = fit_power(data)
    assert np.isfinite(k).all() and np.isfinite(K).all() and np.isfinite(err).all()
    assert K[0] == 1.0 and k[0] == 0.0 and K[2] == pytest.approx(1.0, abs=0.01)
    with pytest.raises(ValueError, match="exponent_range"):
        fit_power(data, exponent_range=(0.0, 1.0))


def test_07_compressed_lookup_matches_the_stack_at_slice_centres():
    rng = np.random.default_rng(2)
    k, K = rng.uniform(0.1, 1, (4, 5, 3)), rng.uniform(0.5, 3, (4, 5, 3))
    x = np.arange(8) / 7
    slices = evaluate_power(k[None], K[None], x[:, None, None, None])
    full = ShadingData(float(slices.mean(axis=(1, 2, 3)).max()) * 0 + 2.0, 8, slices=slices)
    comp = ShadingData(2.0, 8, k_s=k, exponent=K)
    uv = (np.stack(np.meshgrid(np.arange(5) + 0.5, np.arange(4) + 0.5), -1) / [5, 4]).reshape(-1, 2)
    for i in range(8):
        value = np.full((len(uv), 3), 2.0 * i / 7)
        np.testing.assert_allclose(lookup(comp, uv, value), lookup(full, uv, value), rtol=1e-9, atol=1e-12)


# -- lookups and rendering (Eq 2-3, Fig 6) -------------------------------------------------------------------------


def reference_lookup(slices, uv, value, a_max):
    """Slow, obvious trilinear lookup: loops over points and channels."""
    N, V, U, C = slices.shape
    out = np.zeros(value.shape)
    for p in range(len(uv)):
        for c in range(C):
            f = min(max(value[p, c], 0) / a_max, 1.0) * (N - 1)
            fu, fv = uv[p, 0] * U - 0.5, uv[p, 1] * V - 0.5
            acc = 0.0
            for dv in (0, 1):
                for du in (0, 1):
                    wu = (fu - np.floor(fu)) if du else 1 - (fu - np.floor(fu))
                    wv = (fv - np.floor(fv)) if dv else 1 - (fv - np.floor(fv))
                    u, v = int(np.floor(fu) + du) % U, int(np.floor(fv) + dv) % V
                    col = slices[:, v, u, c]
                    acc += wu * wv * np.interp(f, np.arange(N), col)
            out[p, c] = acc
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), scale=st.floats(0.0, 3.0))
def test_08_trilinear_lookup_against_a_slow_reference(seed, scale):
    rng = np.random.default_rng(seed)
    slices = rng.uniform(0, 1, (5, 3, 4, 3))
    uv = rng.uniform(-1.5, 2.5, (20, 2))
    value = rng.uniform(-0.1, 1.2, (20, 3)) * scale
    data = ShadingData(0.8, 5, slices=slices)
    np.testing.assert_allclose(lookup(data, uv, value), reference_lookup(slices, uv, value, 0.8), rtol=1e-10, atol=1e-12)
    above = value > 0.8
    scaled = lookup(data, uv, value, "scale")
    np.testing.assert_allclose(scaled[~above], lookup(data, uv, value)[~above])
    np.testing.assert_allclose(scaled[above], (lookup(data, uv, value) * value / 0.8)[above])


def flat_lambert_data(albedo=0.5):
    meso = Mesostructure(np.zeros((6, 8)), albedo, (4.0, 3.0))
    slices, r, a = linearize(arc_stack(meso, (8, 6), (4.0, 3.0)), 8)
    return ShadingData(float(r[-1]), 8, slices=slices, image_average=a, theta_i_deg=np.array(THETA))


@pytest.mark.parametrize("name,params", [("phong", {"rho_d": [0.1, 0.2, 0.3], "rho_s": 0.4, "exponent": 30.0}),
                                         ("ward", {"rho_d": 0.2, "rho_s": 0.1, "alpha": 0.2}),
                                         ("lambert", {"rho_d": [0.3, 0.5, 0.7]})])
@pytest.mark.parametrize("compressed", [False, True])
def test_09_flat_lambertian_field_reproduces_the_chosen_brdf(name, params, compressed):
    """A flat, uniform Lambertian sample has S(r) = r, so L = σ f_r cos θ_i E for any model (below a_max)."""
    data = flat_lambert_data()
    if compressed:
        k, K, _ = fit_power(data.slices)
        assert np.allclose(K, 1.0)
        data = ShadingData(data.a_max, 8, k_s=k, exponent=K)
    m = model(name)
    rng = np.random.default_rng(3)
    wi, wo, uv = hemisphere(rng, 400), hemisphere(rng, 400), rng.uniform(0, 1, (400, 2))
    E = rng.uniform(0.5, 2.0, (400, 1))
    sigma = 0.3
    expect = sigma * m.eval({k: np.broadcast_to(np.asarray(v, float).reshape(-1), (1, p.channels))
                             for p in m.parameters for k, v in params.items() if k == p.name},
                            wi[None], wo[None])[0] * wi[:, 2:] * E
    r = expect / E
    got = shade(data, m, params, uv, wi, wo, E, sigma=sigma, above_max="scale")
    np.testing.assert_allclose(got, expect, rtol=1e-6, atol=1e-12)
    clamp = shade(data, m, params, uv, wi, wo, E, sigma=sigma, above_max="clamp")
    below = r <= data.a_max
    np.testing.assert_allclose(clamp[below], expect[below], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(clamp[~below], (data.a_max * E * np.ones_like(r))[~below], rtol=1e-6)


def test_10_a_sharper_exponent_makes_the_same_data_more_specular():
    """Fig 6 rows 1-2: Phong exponent 5 vs 60 on the same shading map; the highlight narrows and rises."""
    meso = bumpy(amplitude=0.2)
    slices, r, a = linearize(arc_stack(meso, (32, 24), (8.0, 6.0), shadowing=True), 8)
    data = ShadingData(float(r[-1]), 8, slices=slices)
    n = 64
    xs = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(xs, xs)
    P = np.stack([X - 0.5, Y - 0.5, np.zeros_like(X)], -1) * 200.0          # a 200 mm plane, 4x4 tiles of the map
    uv = np.stack([X * 4 % 1, Y * 4 % 1], -1)
    to = lambda q: (q - P) / np.linalg.norm(q - P, axis=-1, keepdims=True)  # noqa: E731
    wi, wo = to(np.array([-60.0, 0.0, 200.0])), to(np.array([60.0, 0.0, 200.0]))
    out = {}
    for exponent in (5.0, 60.0):
        params = {"rho_d": 0.05, "rho_s": 0.2, "exponent": exponent}
        img = shade(data, model("phong"), params, uv, wi, wo, 1.0, above_max="scale").mean(-1)
        clamped = shade(data, model("phong"), params, uv, wi, wo, 1.0, above_max="clamp")
        assert clamped.max() <= slices[-1].max() + 1e-12    # clamping caps the highlight at the brightest slice
        out[exponent] = img
        # Decoupled: the mesostructure modulates r the same way whatever the BRDF.
        rr = r_value(model("phong"), params, wi, wo).mean(-1)
        assert np.corrcoef(img.ravel(), rr.ravel())[0, 1] > 0.7
    lo, hi = out[5.0], out[60.0]
    assert hi.max() > 1.5 * lo.max()
    assert (hi > 0.5 * hi.max()).mean() < 0.5 * (lo > 0.5 * lo.max()).mean()
    assert not np.allclose(lo / lo.max(), hi / hi.max(), atol=0.05)


def test_11_four_lookup_variants_differ_as_the_paper_describes():
    meso = bumpy(amplitude=0.4)
    imgs = arc_stack(meso, (32, 24), (8.0, 6.0), shadowing=True)
    slices, r, a = linearize(imgs, 8)
    data = ShadingData(float(r[-1]), 8, slices=slices, image_average=a, theta_i_deg=np.array(THETA))
    rng = np.random.default_rng(4)
    wi, wo, uv = hemisphere(rng, 300), hemisphere(rng, 300), rng.uniform(0, 1, (300, 2))
    m, params = model("lambert"), {"rho_d": 0.6}
    res = {v: shade(data, m, params, uv, wi, wo, 1.0, variant=v) for v in VARIANTS}
    assert all(np.isfinite(x).all() and (x >= 0).all() for x in res.values())
    # lookup by r is linear in the light's intensity; lookup by radiance is not
    np.testing.assert_allclose(shade(data, m, params, uv, wi, wo, 3.0), 3 * res["r"], rtol=1e-12)
    rad3 = shade(data, m, params, uv, wi, wo, 3.0, variant="radiance")
    assert not np.allclose(rad3, 3 * res["radiance"], rtol=0.05)
    # the texture variant is one slice times r: its spatial pattern does not change with the light
    ratio = res["texture"] / np.maximum(r_value(m, params, wi, wo), 1e-12)
    np.testing.assert_allclose(ratio, bilinear(slices[-1], uv) / r[-1], rtol=1e-9)
    # with the acquisition's own (Lambertian) BRDF, r = a(θ): the angle lookup equals the r lookup
    tab = angle_table(data)
    assert tab[90] == 0.0 and tab[15] == pytest.approx(a[0])
    on_arc = np.radians(np.array([25.0, 45.0, 65.0]))
    wi2 = np.stack([np.sin(on_arc), 0 * on_arc, np.cos(on_arc)], -1)
    wo2 = np.tile([0.0, 0.0, 1.0], (3, 1))
    sigma = a[[1, 3, 5]] / r_value(m, params, wi2, wo2)[:, 0]
    for j, s in enumerate(sigma):
        x = shade(data, m, params, uv[:5], wi2[j], wo2[j], 1.0, sigma=s, variant="r")
        y = shade(data, m, params, uv[:5], wi2[j], wo2[j], 1.0, sigma=s, variant="angle")
        np.testing.assert_allclose(x, y, rtol=1e-9)


def test_12_environment_lighting_integrates_eq3():
    """Uniform sky of radiance L_e on a flat Lambertian map with a Lambertian BRDF: L_o = π rho_d L_e."""
    data = flat_lambert_data()
    env = np.full((32, 64, 3), 2.0)
    rng = np.random.default_rng(5)
    wo, uv = hemisphere(rng, 10), rng.uniform(0, 1, (10, 2))
    got = shade_environment(data, model("lambert"), {"rho_d": 0.3}, uv, wo, env, resolution=(32, 64), above_max="scale")
    np.testing.assert_allclose(got, 0.3 * np.pi * 2.0, rtol=0.01)   # rho_d is albedo / pi
    rad = shade_environment(data, model("lambert"), {"rho_d": 0.3}, uv, wo, env, resolution=(32, 64), variant="radiance",
                            above_max="scale")
    np.testing.assert_allclose(rad, got, rtol=1e-9)       # S linear: inside or outside the integral agree
    with pytest.raises(ValueError, match="lat-long"):
        shade_environment(data, model("lambert"), {"rho_d": 0.3}, uv, wo, np.full((4, 8), 1.0))


@settings(max_examples=30, deadline=None)
@given(theta=st.floats(0.0, 90.0), exponent=st.floats(1.0, 1e4), variant=st.sampled_from(VARIANTS),
       above=st.sampled_from(["clamp", "scale"]))
def test_13_grazing_angles_and_huge_exponents_stay_finite(theta, exponent, variant, above):
    data = flat_lambert_data()
    t = np.radians(theta)
    wi = np.array([[np.sin(t), 0.0, np.cos(t)], [0.0, 0.0, -1.0]])
    wo = np.array([[-np.sin(t), 0.0, np.cos(t)], [0.0, 0.0, 1.0]])
    out = shade(data, model("phong"), {"rho_d": 0.1, "rho_s": 1.0, "exponent": exponent}, np.array([[0.3, 0.7]] * 2),
                wi, wo, 1.0, variant=variant, above_max=above)
    assert np.isfinite(out).all() and (out >= 0).all() and np.all(out[1] == 0)


def test_14_bad_input_names_the_problem():
    data = flat_lambert_data()
    m = model("phong")
    with pytest.raises(ValueError, match="variant"):
        shade(data, m, {"rho_d": 0.1, "rho_s": 0.1, "exponent": 5}, [0.5, 0.5], [0, 0, 1.0], [0, 0, 1.0], variant="x")
    with pytest.raises(ValueError, match="exponent"):
        shade(data, m, {"rho_d": 0.1, "rho_s": 0.1}, [0.5, 0.5], [0, 0, 1.0], [0, 0, 1.0])
    with pytest.raises(ValueError, match="either slices"):
        ShadingData(1.0, 8)
    with pytest.raises(ValueError, match="image_average"):
        shade(ShadingData(1.0, 8, slices=data.slices), m, {"rho_d": 0.1, "rho_s": 0.1, "exponent": 5}, [0.5, 0.5],
              [0, 0, 1.0], [0, 0, 1.0], variant="angle")
