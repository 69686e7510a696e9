"""The ``separable`` model: factor stores, bilinear lookup, GLSL against numpy, and the svd/nd fitters in a graph."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core.brdf_checks import hemisphere_directions
from sbrdf_core.registry import Registry
from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact
from sbrdf_separable.decompose import nd, parameterization, svd
from sbrdf_separable.factors import Factors, bilinear, cell_centres, load, save
from sbrdf_separable.sources import model_function

REGISTRY = Registry()
WARD = {"rho_d": [1 / np.pi, 0, 0], "rho_s": [0.3] * 3, "alpha_x": [0.21], "alpha_y": [0.048]}


def ward_fn():
    return model_function(REGISTRY.create("brdf-model", "ward", {"anisotropic": True}), WARD)


@pytest.fixture(scope="module")
def ward_svd3(tmp_path_factory):
    """A 3-term SVD (signed later terms) of Ward in Gram–Schmidt, stored as float32."""
    fac = svd(ward_fn(), parameterization("gram-schmidt"), 16, terms=3, clamp_max=5.0)
    path = save(fac, str(tmp_path_factory.mktemp("sep") / "ward.zarr"))
    return fac, path


def test_bilinear_is_exact_at_texel_centres_and_linear_between():
    rng = np.random.default_rng(0)
    tex = rng.normal(size=(2, 8, 8, 3))
    c = cell_centres(8)
    np.testing.assert_allclose(bilinear(tex, c), tex.reshape(2, 64, 3), atol=1e-12)
    mid = (c[0] + c[1]) / 2  # halfway between texels (0, 0) and (0, 1) along u
    np.testing.assert_allclose(bilinear(tex, mid[None])[:, 0], (tex[:, 0, 0] + tex[:, 0, 1]) / 2, atol=1e-12)
    # periodic axis: the seam blends the last and first texels
    seam = np.array([[1.0, c[0, 1]]])
    np.testing.assert_allclose(bilinear(tex, seam, (True, False))[:, 0], (tex[:, 0, 7] + tex[:, 0, 0]) / 2, atol=1e-12)


def test_store_round_trip_rebuilds_the_model_from_its_config(ward_svd3, tmp_path):
    fac, path = ward_svd3
    assert (fac.g[1:] < 0).any() and (fac.h[1:] < 0).any()  # later SVD terms are signed
    model = REGISTRY.create("brdf-model", "separable", {"factors": path})
    rng = np.random.default_rng(1)
    wi, wo = hemisphere_directions(rng, (1, 300)), hemisphere_directions(rng, (1, 300))
    wi[0, :5, 2] *= -1
    f = model.eval({"scale": np.ones((1, 3))}, wi, wo)
    ref = Factors(fac.g, fac.h, "gram-schmidt", {"map": "xy"})
    direct = REGISTRY.create("brdf-model", "separable", {})
    direct.set_factors(ref)
    np.testing.assert_allclose(f, direct.eval({"scale": np.ones((1, 3))}, wi, wo), rtol=1e-6, atol=1e-7)
    assert np.all(f[0, :5] == 0) and np.isfinite(f).all()
    two = REGISTRY.create("brdf-model", "separable", {"factors": path, "terms": 2})
    assert two.factors.terms == 2
    meta = load(path).meta
    assert meta["method"] == "svd" and meta["clamp_max"] == 5.0


@pytest.mark.parametrize("encoding", ["float16", "unorm8"])
def test_signed_factors_survive_biased_8_bit_and_half_storage(ward_svd3, tmp_path, encoding):
    """§6.1: negative factor values stored with a bias and scale decode to within half a code step."""
    fac, _ = ward_svd3
    path = save(fac, str(tmp_path / f"{encoding}.zarr"), encoding)
    back = load(path)
    span = fac.g.max(axis=(1, 2)) - fac.g.min(axis=(1, 2))
    step = span / 255 if encoding == "unorm8" else np.abs(fac.g).max(axis=(1, 2)) * 2**-10
    assert (np.abs(back.g - fac.g) <= step[:, None, None, :] * 0.5 + 1e-12).all()
    np.testing.assert_allclose(fac.encoded(encoding).g, back.g, atol=1e-12)


def test_bad_stores_are_named_in_the_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.zarr"):
        load(str(tmp_path / "missing.zarr"))
    bad = Factors(np.full((1, 4, 4, 3), np.nan), np.ones((1, 4, 4, 3)), "gram-schmidt", {"map": "xy"})
    with pytest.raises(ValueError, match="non-finite"):
        save(bad, str(tmp_path / "nan.zarr"))
    assert not (tmp_path / "nan.zarr").exists()


def test_a_group_where_a_factor_array_should_be_is_named_in_the_error(ward_svd3, tmp_path):
    import shutil

    import zarr

    fac, path = ward_svd3
    copy = shutil.copytree(path, tmp_path / "damaged.zarr")
    shutil.rmtree(copy / "h")
    zarr.open_group(store=str(copy), mode="a").create_group("h")
    with pytest.raises(ValueError, match=r"damaged\.zarr.*'h' is a group, not an array"):
        load(str(copy))


def test_only_the_constant_placeholder_skips_the_tangent_frame(ward_svd3):
    fac, path = ward_svd3
    assert REGISTRY.create("brdf-model", "separable", {}).anisotropic is False
    assert REGISTRY.create("brdf-model", "separable", {"factors": path}).anisotropic is True
    direct = REGISTRY.create("brdf-model", "separable", {})
    direct.set_factors(Factors(fac.g, fac.h, "gram-schmidt", {"map": "xy"}))
    assert direct.anisotropic is True


# -- GLSL against numpy ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gl():
    moderngl = pytest.importorskip("moderngl")
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl")
    except Exception as e:
        pytest.skip(f"no EGL context: {e}")
    fbo = ctx.simple_framebuffer((1, 1))
    fbo.use()
    yield ctx
    fbo.release()
    ctx.release()


def glsl_eval(ctx, model, scale, wi, wo):
    """``brdf_separable`` on ``(S, 3)`` pairs by transform feedback, the factor textures bound as the renderer would."""
    import moderngl

    vs = ("#version 330\nin vec3 in_wi;\nin vec3 in_wo;\nout vec3 f;\nuniform vec3 u_scale;\n" + model.glsl()
          + "void main() { f = brdf_separable(in_wi, in_wo, u_scale); }\n")
    prog = ctx.program(vertex_shader=vs, varyings=["f"])
    prog["u_scale"].value = tuple(float(s) for s in scale)
    textures = []
    for unit, (name, arr) in enumerate(model.gl_textures().items()):
        assert arr.dtype == np.float32 and arr.ndim == 3 and arr.shape[2] <= 4
        tex = ctx.texture((arr.shape[1], arr.shape[0]), arr.shape[2], arr.tobytes(), dtype="f4")
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        tex.repeat_x = tex.repeat_y = False
        tex.use(location=unit)
        prog[name].value = unit
        textures.append(tex)
    vbo = ctx.buffer(np.concatenate([wi, wo], axis=1).astype("f4").tobytes())
    out = ctx.buffer(reserve=wi.shape[0] * 12)
    vao = ctx.vertex_array(prog, [(vbo, "3f 3f", "in_wi", "in_wo")])
    vao.transform(out, mode=moderngl.POINTS, vertices=wi.shape[0])
    res = np.frombuffer(out.read(), dtype="f4").reshape(-1, 3).astype(np.float64)
    for obj in [vao, vbo, out, prog, *textures]:
        obj.release()
    return res


@pytest.mark.parametrize("name,map_", [("gram-schmidt", "xy"), ("gram-schmidt", "parabolic"), ("rusinkiewicz", "xy"),
                                       ("standard", "parabolic"), ("elevation-azimuth", "xy")])
def test_glsl_matches_numpy_lookup(gl, name, map_):
    fac = nd(ward_fn(), parameterization(name, {"map": map_}), 12, terms=2, clamp_max=5.0)
    model = REGISTRY.create("brdf-model", "separable", {})
    model.set_factors(fac)
    rng = np.random.default_rng(2)
    wi, wo = hemisphere_directions(rng, (1, 400))[0], hemisphere_directions(rng, (1, 400))[0]
    keep = (wi[:, 2] > 0.02) & (wo[:, 2] > 0.02)
    wi, wo = wi[keep], wo[keep]
    wi[:6, 2] *= -1  # below the horizon: 0 on both sides
    scale = np.array([1.0, 0.5, 2.0])
    expect = model.eval({"scale": scale[None]}, wi[None], wo[None])[0]
    got = glsl_eval(gl, model, scale, wi, wo)
    assert np.all(got[:6] == 0.0)
    np.testing.assert_allclose(got, expect, rtol=2e-3, atol=2e-4 * np.abs(expect).max())


# -- the fitters in a graph ------------------------------------------------------------------------------------

GRAPH = textwrap.dedent("""\
    name: separable-fit
    store: {store}
    nodes:
      material: {{kind: SampleModel, params: {{model: ward, model_params: {{anisotropic: true}}, texels: [1, 1],
                  params: {{rho_d: [0.3183, 0.0, 0.0], rho_s: [0.3, 0.3, 0.3], alpha_x: 0.21, alpha_y: 0.048}},
                  poses: 3000, directions: random, max_theta_deg: 80.0, size_mm: [0.001, 0.001]}}}}
      nd: {{kind: Fit, plugin: nd, in: {{samples: material}},
            params: {{factors: {factors}, size: 16, clamp_max: 5.0, encoding: unorm8, holdout: 0}}}}
    """)


def test_nd_fitter_in_a_graph_writes_a_model_the_registry_rebuilds(tmp_path):
    factors = tmp_path / "store" / "ward-nd.zarr"  # beside the artifacts: outputs stay in the store
    run_graph(GRAPH.format(store=tmp_path / "store", factors=factors), progress=False)
    art = open_artifact(f"{tmp_path}/store/nd")
    assert art.attrs["model"] == "separable" and art.attrs["model_config"]["factors"] == str(factors)
    np.testing.assert_allclose(art.read("params/scale"), 1.0)
    assert art.read("samples")[0, 0] > 1000 and np.isfinite(art.read("rms")).all()
    model = REGISTRY.create("brdf-model", art.attrs["model"], art.attrs["model_config"])
    assert model.factors.meta["method"] == "nd" and model.factors.meta["encoding"] == "unorm8"
    # the fit reproduces its samples better than the best constant does
    samples = open_artifact(f"{tmp_path}/store/material")
    f = samples.read("f_r")[0, 0].astype(float)
    rms_const = np.sqrt(np.mean((f - f.mean(axis=0)) ** 2))
    assert art.read("rms")[0, 0] < 0.8 * rms_const


def test_separable_fitters_refuse_more_than_one_texel(tmp_path):
    fitter = REGISTRY.create("fitter", "svd", {"factors": str(tmp_path / "f.zarr")})
    rng = np.random.default_rng(0)
    wi, wo = hemisphere_directions(rng, (2, 50)), hemisphere_directions(rng, (2, 50))
    with pytest.raises(ValueError, match="1x1 SampledReflectance"):
        fitter.fit(REGISTRY.create("brdf-model", "separable", {}), np.ones((2, 50, 3)), np.ones((2, 50), bool), wi, wo)
    assert not (tmp_path / "f.zarr").exists()


def test_the_example_graph_validates():
    from pathlib import Path

    from sbrdf_core.graph import load_graph

    g = load_graph(Path(__file__).resolve().parents[2] / "graphs" / "separable.yaml", REGISTRY)
    assert {n.plugin for n in g.nodes.values()} >= {"nd", "svd"}


@pytest.mark.parametrize("sigma", [0.1, 0.35, 1.0])
def test_velvet_fibre_distribution_is_normalised(sigma):
    """Ashikhmin–Premože: ∫ D(h) cos θ_h dω_h = 1 (the inverted Gaussian adds 4σ²/(1 + 4σ²) to 1/π's 1)."""
    from sbrdf_core.brdf_checks import quadrature

    model = REGISTRY.create("brdf-model", "velvet", {})
    h, w = quadrature(256, 64)
    # D(h) read off the model: with ω_i = ω_o = h, D = (f − ρ_d) · 4 (2 cos − cos²) / ρ_s
    params = {"rho_d": np.zeros((1, 3)), "rho_s": np.ones((1, 3)), "sigma": np.full((1, 1), sigma)}
    f = model.eval(params, h[None], h[None])[0, :, 0]
    c = h[:, 2]
    D = f * 4 * (2 * c - c * c)
    assert abs(np.sum(w * D) - 1.0) < 2e-3


def reference_eval(fac, param, wi, wo):
    """Slow reference: scipy's map_coordinates (order 1, edge/wrap modes) per term and channel."""
    from scipy.ndimage import map_coordinates

    x, y = param.coords(wi, wo)
    out = np.zeros((len(wi), 3))
    K = fac.size
    for k in range(fac.terms):
        for c in range(3):
            vals = []
            for tex, uv, wrap in ((fac.g[k, ..., c], x, param.wrap[0]), (fac.h[k, ..., c], y, param.wrap[1])):
                coords = np.stack([uv[:, 1] * K - 0.5, uv[:, 0] * K - 0.5])  # (row = v, column = u)
                mode = "grid-wrap" if wrap[0] else "nearest"
                vals.append(map_coordinates(tex, coords, order=1, mode=mode))
            out[:, c] += vals[0] * vals[1]
    up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(up[:, None], out, 0.0)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31), name=st.sampled_from(["gram-schmidt", "rusinkiewicz", "standard",
                                                          "elevation-azimuth"]),
       theta=st.sampled_from([0.0, 45.0, 89.9, 89.9999, 90.0, 95.0]))
def test_eval_is_finite_zero_below_and_agrees_with_a_slow_reference(seed, name, theta):
    rng = np.random.default_rng(seed)
    fac = nd(ward_fn(), parameterization(name), 8, terms=2, clamp_max=5.0)
    model = REGISTRY.create("brdf-model", "separable", {})
    model.set_factors(fac)
    wi = hemisphere_directions(rng, (60,))
    wo = hemisphere_directions(rng, (60,))
    t, p = np.radians(theta), rng.uniform(0, 2 * np.pi, 20)
    wi[:20] = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.full(20, np.cos(t))], -1)  # grazing, horizon, below
    wo[20:30] = wi[20:30] * [-1, -1, 1]  # mirror pairs: h = n, the Rusinkiewicz singularity
    f = model.eval({"scale": np.ones((1, 3))}, wi[None], wo[None])[0]
    assert np.isfinite(f).all()
    assert np.all(f[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] == 0.0)
    np.testing.assert_allclose(f, reference_eval(fac, parameterization(name), wi, wo), rtol=1e-9, atol=1e-12)
