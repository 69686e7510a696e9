"""The GeForce 4 emulation (pipeline: geforce4): per pixel it is mcallister8.hardware_shade, artifacts included."""

from __future__ import annotations

from dataclasses import replace

import dask.array as da
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sbrdf_core.errors import SbrdfError
from sbrdf_core.registry import Registry
from sbrdf_lib.scene import load_scene
from sbrdf_quantizers.mcallister8 import McAllister8Quantizer, exponent_table, hardware_shade
from sbrdf_render import materials as mat

REGISTRY = Registry()
SIZE, REPEAT = 40.0, 8.0  # a plane far larger than the view: every pixel hits it
# from beyond the plane's far side, so the forward-scattering lobes light up towards the top of the image
LIGHT = np.array([0.0, 1.0, 0.35]) / np.linalg.norm([0.0, 1.0, 0.35])
IRRADIANCE = 2.0


def plane_scene(lights: int = 1, resolution=(96, 72)):
    light = (f"  - {{type: directional, direction: {LIGHT.tolist()}, irradiance: {IRRADIANCE}}}\n") * lights
    return load_scene(f"""
camera: {{position: [0, -2.0, 0.9], look_at: [0, 0, 0], fov_deg: 40, resolution: {list(resolution)}}}
materials: {{s: {{model: lafortune}}}}
objects:
  - {{shape: plane, size: [{SIZE}, {SIZE}], uv_repeat: [{REPEAT}, {REPEAT}], material: s}}
lights:
{light}""")


def lafortune(**cfg):
    return REGISTRY.create("brdf-model", "lafortune", {"lobes": 1, **cfg})


def random_params(model, V, U, rng) -> dict:
    """Fitted-like Lafortune maps: forward lobes of moderate C, exponents 2–200."""
    p = {"rho_d": rng.uniform(0.02, 0.4, (V, U, 3))}
    for j in range(1, model.lobes + 1):
        p[f"rho_s_{j}"] = rng.uniform(0.1, 1.5, (V, U, 3))
        if model.anisotropic:
            p[f"c_x_{j}"], p[f"c_y_{j}"] = rng.uniform(-1.3, -0.6, (V, U, 1)), rng.uniform(-1.3, -0.6, (V, U, 1))
        else:
            p[f"c_xy_{j}"] = rng.uniform(-1.3, -0.6, (V, U, 1))
        p[f"c_z_{j}"] = rng.uniform(0.5, 1.1, (V, U, 1))
        p[f"exponent_{j}"] = np.exp(rng.uniform(np.log(2), np.log(200), (V, U, 1)))
    return p


def hardware_material(model, params, c_range=1.0) -> mat.SceneMaterial:
    """A material as an mcallister8 TextureSet gives it: the codes, and the decoded maps for the float path."""
    q = McAllister8Quantizer(c_range=c_range)
    enc = q.encode({k: da.from_array(v) for k, v in params.items()}, model)
    tex = {k: np.asarray(t.compute()) for k, t in enc.textures.items()}
    dec = q.decode(tex, enc.scale, enc.bias, model)
    maps = np.concatenate([dec[p.name] for p in model.parameters], axis=-1).astype(np.float32)
    return mat.SceneMaterial("s", model, maps, None, "nearest",
                             {"quantizer": "mcallister8", "textures": tex, "scale": enc.scale, "bias": enc.bias})


def pixel_geometry(scene, V, U):
    """Per pixel: texel indices, ω_r in the plane's frame (T = +x, B = +y, N = +z), and whether the pixel is
    clear of texel edges (GL's interpolated uv and the ray's may fall either side of an edge)."""
    dirs, origin = scene.camera.rays()
    dirs = dirs.reshape(-1, 3)
    t = -origin[2] / dirs[:, 2]
    x = origin + t[:, None] * dirs
    assert (t > 0).all() and (np.abs(x[:, :2]) < SIZE / 2).all()  # the plane fills the view
    uv = (x[:, :2] / SIZE + 0.5) * REPEAT
    st_ = uv * [U, V]
    clear = (np.abs(st_ - np.round(st_)) > 1e-3).all(axis=1)
    i = np.floor(st_[:, 0]).astype(int) % U
    j = np.floor(st_[:, 1]).astype(int) % V
    wo = origin - x
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    return j, i, wo, clear


def reference(m, scene, lights=1):
    """hardware_shade at every pixel's own directions × irradiance, and its 8-bit tolerance."""
    tex, scale, bias = m.encoded["textures"], m.encoded["scale"], m.encoded["bias"]
    V, U = tex["rho_d"].shape[:2]
    j, i, wo, clear = pixel_geometry(scene, V, U)
    per_pixel = {k: t[j, i] for k, t in tex.items()}
    wi = np.broadcast_to(LIGHT, wo.shape)
    E = IRRADIANCE * LIGHT[2] * lights
    f = hardware_shade(per_pixel, scale, bias, wi[:, None], wo[:, None])[:, 0]
    # Tolerance from the 8-bit steps.  The GL computes x in float32 and the reference in float64, so where
    # 255·x' lies within float error of a rounding tie the p-buffer may hold the neighbouring code i ± 1;
    # the table then answers a neighbouring row, off by |T[i±1, n'] − T[i, n']| / 255 (large for big n'
    # near x' = 1), times ρ_s.  On top: the RGBA16F frame's rounding, 2⁻¹⁰ relative (11-bit mantissa,
    # truncated by llvmpipe) for each pass 2's output and for each blend's sum.
    T = exponent_table().astype(np.float64)
    step = np.zeros(len(wo))
    k = 1
    while f"lobe_{k}" in tex:
        val = per_pixel[f"lobe_{k}"] * scale[f"lobe_{k}"] + bias[f"lobe_{k}"]
        x = np.einsum("pk,pk->p", val[:, :3] * wi, wo)
        row = np.clip(np.round(255.0 * np.clip(x, 0, 1) ** 2), 0, 255).astype(int)
        n = per_pixel[f"lobe_{k}"][:, 3].astype(int)
        up, down = T[np.minimum(row + 1, 255), n], T[np.maximum(row - 1, 0), n]
        jump = np.maximum(np.abs(up - T[row, n]), np.abs(down - T[row, n]))
        step += (per_pixel[f"rho_s_{k}"].astype(np.float64) / 255.0).max(axis=1) * jump / 255.0
        k += 1
    H, W = scene.camera.resolution[::-1]
    img = (f * E).reshape(H, W, 3)
    tight = 2.0**-10 * 2 * (k - 1) * lights * np.abs(img) + 1e-5
    return img, tight, tight + (step * E).reshape(H, W, 1), clear.reshape(H, W)


def draw(drawer_cls, scene, materials):
    s = drawer_cls(scene, materials)
    try:
        return s.draw()
    finally:
        s.release()


@pytest.mark.parametrize("cfg", [{"lobes": 1}, {"lobes": 2, "anisotropic": True}])
def test_emulation_is_hardware_shade_per_pixel(gl, cfg):
    from sbrdf_render.gf4 import GF4Scene

    model = lafortune(**cfg)
    m = hardware_material(model, random_params(model, 4, 4, np.random.default_rng(7)))
    scene = plane_scene()
    frame = draw(GF4Scene, scene, {"s": m})
    ref, tight, tol, clear = reference(m, scene)
    err = np.abs(frame.image - ref)
    assert clear.mean() > 0.9
    assert (err[clear] <= tol[clear]).all(), f"worst excess {np.max(err - tol)}"
    # ...and almost everywhere the very same table entries: only rounding ties may pick a neighbouring row
    assert (err <= tight).all(axis=-1)[clear].mean() > 0.97
    assert ref.max() > 0.3  # the highlight is in view: the comparison covers the table's steep part


def test_passes_are_two_per_lobe_per_light(gl):
    from sbrdf_render.gf4 import GF4Scene

    for lobes, lights in [(1, 1), (3, 1), (2, 3)]:
        model = lafortune(lobes=lobes)
        m = hardware_material(model, random_params(model, 2, 2, np.random.default_rng(lobes)))
        frame = draw(GF4Scene, plane_scene(lights, (16, 12)), {"s": m})
        assert frame.stats["passes"] == 2 * lobes * lights  # Table 6.2
        ref, _, tol, clear = reference(m, plane_scene(lights, (16, 12)), lights)
        assert (np.abs(frame.image - ref)[clear] <= lights * tol[clear]).all()  # lights add up in the blend


def test_float_pipeline_keeps_the_grazing_reflection_the_clamp_removes(gl):
    """C_xy = −1.2 (c_range 2 keeps |C| > 1): towards grazing x > 1 and the float pow brightens; the emulation's
    x clamped at 1 cannot.  Where x < 0.9 both agree up to the 8-bit table."""
    from sbrdf_render.gf4 import GF4Scene

    model = lafortune()
    params = {"rho_d": np.full((1, 1, 3), 0.05), "rho_s_1": np.full((1, 1, 3), 1.0), "c_xy_1": np.full((1, 1, 1), -1.2),
              "c_z_1": np.full((1, 1, 1), 0.3), "exponent_1": np.full((1, 1, 1), 6.0)}
    m = hardware_material(model, params, c_range=2.0)
    scene = plane_scene()
    emulated = draw(GF4Scene, scene, {"s": m}).image.astype(np.float64)
    float_ = draw(gl.GLScene, scene, {"s": m}).image.astype(np.float64)
    c_xy, c_z = m.maps[0, 0, 6], m.maps[0, 0, 7]  # decoded, packed as rho_d, rho_s_1, c_xy_1, c_z_1, exponent_1
    _, _, wo, _ = pixel_geometry(scene, 1, 1)
    x = (c_xy * (LIGHT[0] * wo[:, 0] + LIGHT[1] * wo[:, 1]) + c_z * LIGHT[2] * wo[:, 2]).reshape(emulated.shape[:2])
    grazing, normal = x > 1.1, x < 0.9
    assert grazing.mean() > 0.05 and normal.mean() > 0.05
    ratio = float_[..., 1] / emulated[..., 1]
    # float: ρ_d + ρ_s x^n with x^n ≥ 1.1^6 ≈ 1.77 where the emulation's lobe is at most 1
    assert np.median(ratio[grazing]) > 1.4 and ratio[grazing].min() > 1.2
    assert np.median(np.abs(ratio[normal] - 1)) < 0.03


def test_emulation_never_exceeds_the_clamped_lobe_bound(gl):
    """Hard cases (grazing view, exponents up to the model's bound, |C| > 1): finite, and never above
    (ρ_d + Σ ρ_s)·E, since the table's entries are at most 1 — the x-clamp artifact as an invariant."""
    from sbrdf_render.gf4 import GF4Scene

    @settings(max_examples=8, deadline=None, suppress_health_check=list(HealthCheck))
    @given(c_xy=st.floats(-3.0, 3.0), c_z=st.floats(0.05, 3.0), exponent=st.floats(0.1, 20000.0),
           rho_s=st.floats(0.0, 50.0))
    def check(c_xy, c_z, exponent, rho_s):
        model = lafortune()
        params = {"rho_d": np.full((1, 1, 3), 0.1), "rho_s_1": np.full((1, 1, 3), rho_s),
                  "c_xy_1": np.full((1, 1, 1), c_xy), "c_z_1": np.full((1, 1, 1), c_z),
                  "exponent_1": np.full((1, 1, 1), exponent)}
        m = hardware_material(model, params, c_range=2.0)
        img = draw(GF4Scene, plane_scene(1, (24, 18)), {"s": m}).image
        bound = (m.maps[0, 0, 0:3] + m.maps[0, 0, 3:6]) * IRRADIANCE * LIGHT[2]
        assert np.isfinite(img).all() and (img >= 0).all()
        assert (img <= bound * (1 + 2.0**-10) + 1e-5).all()

    check()


def test_parameter_maps_are_encoded_on_the_fly_and_alpha_kills(gl):
    """A float material (no TextureSet) is quantized with mcallister8 first; ρ_d's alpha kills fragments."""
    from sbrdf_render.gf4 import GF4Scene

    model = lafortune()
    params = random_params(model, 2, 2, np.random.default_rng(3))
    maps = np.concatenate([params[p.name] for p in model.parameters], axis=-1).astype(np.float32)
    alpha = np.array([[1.0, 0.0], [1.0, 1.0]], np.float32)
    plain = mat.SceneMaterial("s", model, maps, alpha, "nearest")
    scene = replace(plane_scene(), background=np.full(3, -1.0))  # a sentinel no shaded pixel can take
    frame = draw(GF4Scene, scene, {"s": plain})
    ref_m = hardware_material(model, params)
    ref, _, tol, clear = reference(ref_m, scene)
    V, U = 2, 2
    j, i, _, _ = pixel_geometry(scene, V, U)
    killed = (alpha[j, i] < 0.5).reshape(ref.shape[:2])
    assert killed.mean() > 0.1
    assert (frame.image[killed & clear] == -1.0).all()  # the background shows through
    keep = ~killed & clear
    assert (np.abs(frame.image - ref)[keep] <= tol[keep]).all()


def test_non_lafortune_and_beta_are_refused(gl):
    from sbrdf_render.gf4 import GF4Scene

    phong = REGISTRY.create("brdf-model", "phong", {})
    with pytest.raises(SbrdfError, match="Lafortune lobes only"):
        GF4Scene(plane_scene(1, (8, 6)), {"s": mat.uniform("s", phong, {})})
    beta = lafortune(anisotropic=True, beta=True)
    with pytest.raises(SbrdfError, match="β"):
        GF4Scene(plane_scene(1, (8, 6)), {"s": mat.uniform("s", beta, {})})


def test_render_node_draws_an_mcallister8_texture_set_through_the_geforce4_pipeline(gl, tmp_path):
    """Graph end to end: fit -> Quantize mcallister8 -> Render gl (pipeline: geforce4) uses the stored 8-bit codes."""
    from sbrdf_core.io import read_exr
    from sbrdf_core.runner import run_graph
    from sbrdf_core.store import open_artifact

    (tmp_path / "scene.yaml").write_text("""
camera: {position: [0, -1.5, 1.2], look_at: [0, 0, 0], fov_deg: 45, resolution: [48, 36]}
objects: [{shape: plane, size: [1.5, 1.5]}]
lights: [{type: directional, direction: [0, 1, 0.6], irradiance: 2}, {type: point, position: [1, -1, 2], intensity: 4}]
""")
    graph = tmp_path / "g.yaml"
    graph.write_text(f"""
name: gf4
store: {tmp_path / 'runs'}
nodes:
  samples: {{kind: SampleModel, params: {{model: lafortune, model_params: {{lobes: 1}}, texels: [8, 6], poses: 80,
            noise: 0.002, directions: random}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lafortune, model_params: {{lobes: 1}}}}}}
  hw8: {{kind: Quantize, plugin: mcallister8, in: {{params: fit}}}}
  gf4: {{kind: Render, plugin: gl, in: {{material: hw8}}, params: {{scene: scene.yaml, pipeline: geforce4, frames: 2}}}}
  float: {{kind: Render, plugin: gl, in: {{material: hw8}}, params: {{scene: scene.yaml}}}}
""")
    run_graph(graph.read_text().replace("scene.yaml", str(tmp_path / "scene.yaml")), progress=False)
    gf4 = read_exr(str(tmp_path / "runs" / "gf4" / "image.exr"))
    float_ = read_exr(str(tmp_path / "runs" / "float" / "image.exr"))
    assert gf4.shape == (36, 48, 3) and np.isfinite(gf4).all() and gf4.max() > 0
    assert open_artifact(f"{tmp_path / 'runs'}/gf4").attrs["pipeline"] == "geforce4"
    # the same decoded material: the two pipelines differ only by the 8-bit table, the x clamp and the
    # per-vertex irradiance of the point light (a 2-triangle plane), so they agree broadly
    rel = np.abs(gf4 - float_).sum() / float_.sum()
    assert 0 < rel < 0.5


def test_shadows_are_drawn_when_the_scene_asks(gl):
    """``shadows: true`` zeroes each light's term in the geforce4 frame where the CPU reference's shadow rays to that
    light are blocked, and leaves lit pixels as they were (issue 23: the pipeline used to ignore the flag)."""
    from sbrdf_render.cpu import render_scene
    from sbrdf_render.gf4 import GF4Scene

    from .test_render import interior

    scene = load_scene("""
camera: {position: [0, -2.2, 2.0], look_at: [0, 0, 0.2], fov_deg: 45, resolution: [96, 72]}
materials: {s: {model: lafortune}}
objects:
  - {shape: plane, size: [3, 3], material: s}
  - {shape: sphere, radius: 0.35, material: s, transform: {translate: [0, 0, 0.5]}}
lights: [{type: point, position: [0.8, 0.5, 2.5], intensity: 6}, {type: directional, direction: [-1, 0, 1], irradiance: 0.4}]
shadows: true
""")
    model = lafortune()
    m = {"s": mat.uniform("s", model, {"rho_d": 0.3, "rho_s_1": 0.3, "c_xy_1": -0.8, "c_z_1": 0.8, "exponent_1": 8.0})}
    inside = interior(scene, m)
    total = 0.0
    for light in scene.lights:  # per light: the shading models differ (8 bits, per-vertex E), visibility must not
        one = replace(scene, lights=[light])
        ref, ref_plain = (render_scene(s, m)[0].sum(-1) for s in (one, replace(one, shadows=False)))
        got, got_plain = (draw(GF4Scene, s, m).image.astype(np.float64).sum(-1)
                          for s in (one, replace(one, shadows=False)))
        total = total + draw(GF4Scene, one, m).image.astype(np.float64)
        seen = inside & (ref_plain > 1e-3) & (got_plain > 1e-3)
        blocked, lit = seen & (ref < 1e-6), seen & (ref > 0.999 * ref_plain)
        assert blocked.sum() > 50  # the sphere's shadow from this light
        # all but the pixels along shadow edges (a shadow-map texel, percentage-closer filtered) agree
        assert np.mean(got[blocked] < 0.01 * got_plain[blocked]) > 0.95
        assert np.mean(np.abs(got[lit] / got_plain[lit] - 1.0) < 1e-3) > 0.99
    both = draw(GF4Scene, scene, m).image.astype(np.float64)  # two lights: the sum of each one's shadowed frame
    assert np.mean(np.abs(both - total)[inside] < 1e-2 * np.abs(total).max()) > 0.99
