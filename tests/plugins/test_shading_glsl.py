"""The shading-map GLSL (sbrdf_shading.glsl) against the NumPy lookups, on a real EGL context (transform feedback)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from sbrdf_core.registry import default_registry
from sbrdf_shading.compress import fit_power
from sbrdf_shading.glsl import shading_glsl, uniform_values
from sbrdf_shading.linearize import linearize
from sbrdf_shading.shade import VARIANTS, ShadingData, shade, shade_environment

PHONG = {"rho_d": [0.05, 0.08, 0.1], "rho_s": [0.3, 0.2, 0.1], "exponent": 20.0}


@pytest.fixture(scope="module")
def gl():
    moderngl = pytest.importorskip("moderngl")
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl")
    except Exception as e:  # no EGL: nothing to compile against
        pytest.skip(f"no EGL context: {e}")
    fbo = ctx.simple_framebuffer((1, 1))  # a surfaceless EGL context draws nothing without one
    fbo.use()
    yield ctx
    fbo.release()
    ctx.release()


@pytest.fixture(scope="module")
def data():
    """A non-linear shading map (per texel power laws of different exponents) with acquisition metadata."""
    rng = np.random.default_rng(7)
    V, U, N = 6, 8, 8
    k = rng.uniform(0.2, 0.6, (V, U, 3))
    K = rng.uniform(0.5, 2.5, (V, U, 3))
    theta = np.array([15.0, 30.0, 45.0, 60.0, 75.0])
    images = k[None] * np.cos(np.radians(theta))[:, None, None, None] ** K[None]
    slices, r, a = linearize(images, N)
    return ShadingData(float(r[-1]), N, slices=slices.astype(np.float32), image_average=a, theta_i_deg=theta)


def run_glsl(ctx, src, data, uniforms, uv, wi, wo, E, compressed, call="shade(in_uv, in_wi, in_wo, in_E)"):
    import moderngl

    vs = ("#version 330\nin vec2 in_uv;\nin vec3 in_wi;\nin vec3 in_wo;\nin vec3 in_E;\nout vec3 L;\n" + src +
          f"\nvoid main() {{ L = {call}; }}\n")
    prog = ctx.program(vertex_shader=vs, varyings=["L"])
    for name, value in uniforms.items():
        if name in prog:
            prog[name].write(np.asarray(value, dtype="f4").tobytes())
    textures = []
    if compressed:
        for unit, (name, arr) in enumerate((("u_k_s_map", data.k_s), ("u_exponent_map", data.exponent))):
            V, U, _ = arr.shape
            tex = ctx.texture((U, V), 3, np.ascontiguousarray(arr, "f4").tobytes(), dtype="f4")
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            tex.repeat_x = tex.repeat_y = True
            tex.use(unit)
            prog[name].value = unit
            textures.append(tex)
    else:
        N, V, U, _ = data.slices.shape
        tex = ctx.texture3d((U, V, N), 3, np.ascontiguousarray(data.slices, "f4").tobytes(), dtype="f4")
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        tex.repeat_x = tex.repeat_y = True
        tex.repeat_z = False
        tex.use(0)
        prog["u_shading_map"].value = 0
        textures.append(tex)
    n = len(uv)
    vbo = ctx.buffer(np.concatenate([uv, wi, wo, E], axis=1).astype("f4").tobytes())
    out = ctx.buffer(reserve=n * 12)
    names = [("in_uv", 2), ("in_wi", 3), ("in_wo", 3), ("in_E", 3)]
    fmt = " ".join(f"{k}f" if n in prog else f"{4 * k}x" for n, k in names)   # unused inputs are compiled out
    vao = ctx.vertex_array(prog, [(vbo, fmt, *[n for n, _ in names if n in prog])])
    vao.transform(out, mode=moderngl.POINTS, vertices=n)
    res = np.frombuffer(out.read(), dtype="f4").reshape(-1, 3).astype(np.float64)
    for obj in (vao, vbo, out, prog, *textures):
        obj.release()
    return res


def inputs(n=256, seed=0):
    rng = np.random.default_rng(seed)
    def hemi():
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.02
        return v / np.linalg.norm(v, axis=-1, keepdims=True)
    wi, wo = hemi(), hemi()
    wi[:4, 2] *= -1                                           # below the horizon: black
    return rng.uniform(-0.5, 1.5, (n, 2)), wi, wo, rng.uniform(0.5, 4.0, (n, 3))


@pytest.mark.parametrize("compressed", [False, True], ids=["stack", "compressed"])
@pytest.mark.parametrize("above_max", ["clamp", "scale"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_glsl_matches_numpy(gl, data, variant, above_max, compressed):
    model = default_registry().create("brdf-model", "phong", {})
    if compressed:
        k, K, _ = fit_power(data.slices)
        data = ShadingData(data.a_max, data.n_slices, k_s=k.astype(np.float32), exponent=K.astype(np.float32),
                           image_average=data.image_average, theta_i_deg=data.theta_i_deg)
    uv, wi, wo, E = inputs()
    sigma = 0.7
    src = shading_glsl(model, variant=variant, above_max=above_max, compressed=compressed)
    got = run_glsl(gl, src, data, uniform_values(data, model, PHONG, variant=variant, sigma=sigma), uv, wi, wo, E,
                   compressed)
    expect = shade(data, model, PHONG, uv, wi, wo, E, sigma=sigma, variant=variant, above_max=above_max)
    assert np.all(got[:4] == 0.0)
    np.testing.assert_allclose(got, expect, rtol=5e-3, atol=2e-3 * np.abs(expect).max())


def test_glsl_declares_exactly_the_uniforms_it_uses(data):
    model = default_registry().create("brdf-model", "ward", {})
    for variant in VARIANTS:
        for compressed in (False, True):
            src = shading_glsl(model, variant=variant, compressed=compressed)
            declared = set(re.findall(r"uniform \w+ (\w+)", src))
            values = uniform_values(data, model, {"rho_d": 0.1, "rho_s": 0.1, "alpha": 0.2}, variant=variant)
            samplers = {"u_k_s_map", "u_exponent_map"} if compressed else {"u_shading_map"}
            assert declared == set(values) | samplers


def test_glsl_refuses_what_it_cannot_do():
    reg = default_registry()
    assert "vec3[2](" in shading_glsl(reg.create("brdf-model", "lafortune", {"lobes": 2}))  # lobes via glsl_call
    with pytest.raises(ValueError, match="variant"):
        shading_glsl(reg.create("brdf-model", "phong", {}), variant="nearest")


@pytest.mark.parametrize("variant", ["r", "radiance", "angle"])
def test_glsl_environment_matches_numpy(gl, data, variant):
    """Eq 3 over a pooled lat-long sky: the GLSL loop over u_env_dir/u_env_radiance equals shade_environment."""
    model = default_registry().create("brdf-model", "phong", {})
    rows = np.linspace(0, 1, 32)[:, None, None]
    env = np.broadcast_to(np.concatenate([1.5 - rows, 0.5 + rows, np.ones_like(rows)], -1), (32, 64, 3)).copy()
    env[2:6, 10:20] = 20.0                                       # a bright window
    uv, wi, wo, E = inputs(64, seed=3)
    uniforms = uniform_values(data, model, PHONG, variant=variant, environment=env, environment_resolution=(8, 16))
    D = len(uniforms["u_env_dir"])
    assert D == 64
    src = shading_glsl(model, variant=variant, environment_samples=D)
    got = run_glsl(gl, src, data, uniforms, uv, wi, wo, E, False, call="shade_environment(in_uv, in_wo)")
    expect = shade_environment(data, model, PHONG, uv, wo, env, variant=variant, resolution=(8, 16))
    np.testing.assert_allclose(got, expect, rtol=5e-3, atol=2e-3 * np.abs(expect).max())
