"""SVD and normalized decomposition (seed 001 §4) and the shapes of its error analysis (§5.2, Figs 5 and 6)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core.brdf_checks import hemisphere_directions
from sbrdf_core.registry import Registry
from sbrdf_separable.decompose import GridSampler, nd, parameterization, svd
from sbrdf_separable.error import CLAMP, STUDY, factors_function, radiance_rms, study_brdf
from sbrdf_separable.sources import ScatteredBRDF, model_function

REGISTRY = Registry()
PARAMS = ["gram-schmidt", "rusinkiewicz", "standard", "elevation-azimuth"]


def grid_error(fn, param, fac):
    """RMS over the valid grid points of M − Σ g h (what the SVD minimises)."""
    s = GridSampler(fn, param, fac.size)
    M, valid = s.block(0, s.n)
    rec = np.einsum("kxc,kyc->xyc", fac.g.reshape(fac.terms, -1, 3), fac.h.reshape(fac.terms, -1, 3))
    return float(np.sqrt(np.mean(((M - rec)[valid]) ** 2)))


@pytest.fixture(scope="module")
def study16():
    """§5.2 at K = 16: MC radiance RMS per (material, parameterization) for SVD with 1..4 terms and 1-term ND."""
    out = {}
    for m in STUDY:
        fn = study_brdf(m, REGISTRY)
        for p in PARAMS:
            P = parameterization(p)
            S = svd(fn, P, 16, terms=4, clamp_max=CLAMP)
            N = nd(fn, P, 16, terms=1, clamp_max=CLAMP)
            out[m, p] = {"svd": [radiance_rms(fn, factors_function(S.truncated(k))) for k in (1, 2, 4)],
                         "nd1": radiance_rms(fn, factors_function(N)),
                         "grid": [grid_error(fn, P, S.truncated(k)) for k in (1, 2, 4)],
                         "zero": radiance_rms(fn, lambda wi, wo: np.zeros_like(wi))}
    return out


# -- exactness ---------------------------------------------------------------------------------------------


def separable_in(P):
    def fn(wi, wo):  # a(x) b(y) in this parameterization's own coordinates, coloured
        x, y = P.coords(wi, wo)
        a = 1.0 + np.sin(3 * x[:, 0]) ** 2 + x[:, 1]
        b = np.exp(-4 * ((y[:, 0] - 0.4) ** 2 + (y[:, 1] - 0.6) ** 2))
        return (a * b)[:, None] * np.array([1.0, 0.5, 0.25])

    return fn


@pytest.mark.parametrize("name", ["standard", "elevation-azimuth"])
@pytest.mark.parametrize("p", [1.0, 2.0, 4.0])
def test_a_separable_function_is_reproduced_exactly_on_the_grid(name, p):
    """Every grid point is a real direction pair here: ND (any p) and SVD are exact for a product a(x) b(y)."""
    P = parameterization(name)
    fn = separable_in(P)
    for fac in (nd(fn, P, 12, p=p), svd(fn, P, 12)):
        assert grid_error(fn, P, fac) < 1e-6  # float32 matrix for the SVD


@pytest.mark.parametrize("name", ["rusinkiewicz", "gram-schmidt"])
def test_missing_grid_points_are_imputed_not_fitted(name):
    """Half/difference grids have points below the horizon: treated as missing, filled by EM-style passes,
    the product is recovered ever closer (ND) or at once (SVD)."""
    P = parameterization(name)
    fn = separable_in(P)
    e0, e8 = (grid_error(fn, P, nd(fn, P, 12, impute=k)) for k in (0, 8))
    assert e8 < 0.15 * e0
    assert grid_error(fn, P, svd(fn, P, 12, impute=3)) < 0.25 * e0


def test_more_nd_terms_fit_the_residual():
    P = parameterization("standard")

    def fn(wi, wo):  # rank 2 in the standard parameterization
        return (wi[:, 2] * wo[:, 2] + 0.5 * (1 + wi[:, 0]) * (1 + wo[:, 1]))[:, None] * np.ones(3)

    one, two = nd(fn, P, 12, terms=1), nd(fn, P, 12, terms=2)
    assert grid_error(fn, P, two) < 0.5 * grid_error(fn, P, one)
    assert (two.h[1] < 0).any()  # residual terms are signed


# -- the shapes of §5.2 ------------------------------------------------------------------------------------


def test_svd_grid_error_falls_with_every_term(study16):
    for key, r in study16.items():
        g = r["grid"]
        assert g[0] > g[1] > g[2], (key, g)


@pytest.mark.parametrize("material", ["copper", "velvet"])
def test_svd_radiance_error_falls_with_terms(study16, material):
    for p in PARAMS:
        e = study16[material, p]["svd"]
        assert e[2] < e[0] and e[2] < study16[material, p]["zero"], (p, e)


def test_microfacet_brdfs_prefer_halfvector_parameterizations(study16):
    """§5.2: Ward and rough metal are best in a halfvector parameterization, far better than incident/view."""
    for m in ("ward", "copper"):
        best_half = min(study16[m, "gram-schmidt"]["svd"][0], study16[m, "rusinkiewicz"]["svd"][0])
        assert best_half < 0.8 * study16[m, "standard"]["svd"][0]


def test_one_term_nd_is_close_to_one_term_svd(study16):
    """Fig 6 (Gram–Schmidt, Ward): 1-term ND within 25 % of 1-term SVD; no worse than 2x for the others."""
    r = study16["ward", "gram-schmidt"]
    assert 0.75 < r["nd1"] / r["svd"][0] < 1.25
    for m in STUDY:
        r = study16[m, "gram-schmidt"]
        assert r["nd1"] < 2.0 * r["svd"][0]


def test_error_falls_with_texture_size():
    fn, P = study_brdf("ward", REGISTRY), parameterization("gram-schmidt")
    for method in (nd, svd):
        e8, e24 = (radiance_rms(fn, factors_function(method(fn, P, k, clamp_max=CLAMP))) for k in (8, 24))
        assert e24 < 0.8 * e8, (method.__name__, e8, e24)


@pytest.mark.slow
@pytest.mark.parametrize("material", list(STUDY))
def test_svd_radiance_error_falls_with_terms_at_the_texts_size(material):
    """The text's setting, 32 samples per dimension: 8 terms beat 1 in every parameterization."""
    fn = study_brdf(material, REGISTRY)
    for p in PARAMS:
        S = svd(fn, parameterization(p), 32, terms=8, clamp_max=CLAMP)
        e1, e8 = (radiance_rms(fn, factors_function(S.truncated(k))) for k in (1, 8))
        assert e8 < e1, (p, e1, e8)


def test_singular_configuration_is_smooth_in_gram_schmidt_and_jumps_in_rusinkiewicz():
    """The fitted models at mirror pairs (h = n) perturbed by 1e-9: Gram–Schmidt's value is stable,
    Rusinkiewicz's depends on the direction of the perturbation (§5.1's instability)."""
    fn = study_brdf("ward", REGISTRY)
    rng = np.random.default_rng(3)
    t = np.radians(35.0)
    wi0, wo0 = np.array([np.sin(t), 0, np.cos(t)]), np.array([-np.sin(t), 0, np.cos(t)])
    wi = wi0 + rng.normal(size=(64, 3)) * 1e-9
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = np.repeat(wo0[None], 64, 0)
    spread = {}
    for p in ("gram-schmidt", "rusinkiewicz"):
        f = factors_function(nd(fn, parameterization(p), 16, clamp_max=CLAMP))(wi, wo)[:, 1]
        assert np.isfinite(f).all()
        spread[p] = (f.max() - f.min()) / f.mean()
    assert spread["gram-schmidt"] < 1e-5
    assert spread["rusinkiewicz"] > 1e-2


# -- memory: ND streams, SVD holds the matrix ------------------------------------------------------------


def peak_bytes(call):
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_nd_memory_is_the_factors_not_the_matrix():
    fn, P, K = study_brdf("copper", REGISTRY), parameterization("gram-schmidt"), 24
    matrix = 3 * K**4 * 4  # float32, three channels
    nd(fn, P, 4, terms=2), svd(fn, P, 4)  # imports (scipy.ndimage, ARPACK) are not the algorithm's memory
    nd_peak = peak_bytes(lambda: nd(fn, P, K, terms=1, block_pairs=K * K))
    svd_peak = peak_bytes(lambda: svd(fn, P, K, block_pairs=16 * K * K))
    assert svd_peak > matrix
    assert nd_peak < 0.1 * matrix


# -- hard input ---------------------------------------------------------------------------------------------


@settings(max_examples=15, deadline=None)
@given(scale=st.sampled_from([0.0, 1e-8, 1.0, 1e6]), nan_fraction=st.sampled_from([0.0, 0.1, 1.0]),
       method=st.sampled_from(["nd", "svd"]), name=st.sampled_from(PARAMS), terms=st.integers(1, 3))
def test_factors_stay_finite_on_nan_zero_and_huge_input(scale, nan_fraction, method, name, terms):
    rng = np.random.default_rng(0)

    def fn(wi, wo):
        f = scale * (0.1 + np.exp(-20 * (1 - (wi + wo)[:, 2] / np.linalg.norm(wi + wo, axis=1))))[:, None] * np.ones(3)
        f[rng.random(len(f)) < nan_fraction] = np.nan
        return f

    P = parameterization(name)
    fac = (nd if method == "nd" else svd)(fn, P, 6, terms=terms)
    assert np.isfinite(fac.g).all() and np.isfinite(fac.h).all()
    assert (fac.meta["nonfinite_samples"] > 0) == (nan_fraction > 0)
    wi, wo = hemisphere_directions(rng, (50,)), hemisphere_directions(rng, (50,))
    assert np.isfinite(factors_function(fac)(wi, wo)).all()
    if scale == 0.0 or nan_fraction == 1.0:
        assert np.abs(fac.g).max() * np.abs(fac.h).max() == 0.0


def test_clamp_limits_the_range_before_decomposing():
    fn, P = study_brdf("ward", REGISTRY), parameterization("gram-schmidt")
    raw = model_function(REGISTRY.create("brdf-model", "ward", {"anisotropic": True}), STUDY["ward"][2])
    s = GridSampler(raw, P, 12, clamp_max=2.0)
    M, _ = s.block(0, s.n)
    assert M.max() <= 2.0 and M.min() >= 0.0
    assert GridSampler(raw, P, 12).block(0, s.n)[0].max() > 2.0
    assert fn  # the study's own clamp


def test_scattered_samples_decompose_like_the_analytic_brdf():
    """A measured material (scattered samples, some NaN) interpolated onto the grid gives nearly the analytic ND."""
    fn, P = study_brdf("copper", REGISTRY), parameterization("gram-schmidt")
    rng = np.random.default_rng(4)
    wi, wo = hemisphere_directions(rng, (20000,)), hemisphere_directions(rng, (20000,))
    f = fn(wi, wo)
    f[:500] = np.nan
    valid = np.ones(20000, bool)
    src = ScatteredBRDF(wi, wo, f, valid, P, neighbours=4)
    assert src.samples == 19500
    e_scattered = radiance_rms(fn, factors_function(nd(src, P, 12)))
    e_analytic = radiance_rms(fn, factors_function(nd(fn, P, 12)))
    assert e_scattered < 1.5 * e_analytic
    with pytest.raises(ValueError, match="no valid BRDF samples"):
        ScatteredBRDF(wi, wo, f, np.zeros(20000, bool), P)
