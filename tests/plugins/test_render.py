"""Scenes, the cpu reference renderer and the gl renderer: agreement, closed forms, variants, errors."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core.errors import GraphError, SbrdfError
from sbrdf_lib.mesh import load_obj
from sbrdf_lib.scene import SceneError, load_scene
from sbrdf_lib.surface import tessellate, vertex_frames
from sbrdf_render import materials as mat
from sbrdf_render.cpu import cast, render_scene

from .test_models import CONFIGS, REGISTRY


def draw_gl(gl, scene, materials):
    s = gl.GLScene(scene, materials)
    try:
        return s.draw().image.astype(np.float64), s
    finally:
        s.release()


def interior(scene, materials, margin_uv: float | None = None, texels: tuple[int, int] | None = None) -> np.ndarray:
    """Pixels whose 3×3 neighbourhood hits one object (no silhouettes) and, for nearest lookups, away from texel edges.

    With antialiasing every sub-sample of the pixel (the scene's n×n pattern) must hit that object and keep the margin.
    """
    n = scene.subpixels
    dirs, origin = scene.supersampled().camera.rays()
    H, W = dirs.shape[0] // n, dirs.shape[1] // n
    hits, which = cast(scene, materials, dirs.reshape(-1, 3), origin)
    blocks = which.reshape(H, n, W, n)
    w = blocks[:, 0, :, 0]
    ok = (w >= 0) & (blocks == w[:, None, :, None]).all(axis=(1, 3))
    pad = np.pad(w, 1, mode="edge")
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ok &= pad[1 + dy:1 + dy + H, 1 + dx:1 + dx + W] == w
    ok[[0, -1], :] = ok[:, [0, -1]] = False
    if margin_uv is not None:
        f = (hits.uv * np.asarray(texels)) % 1.0
        ok &= ((np.minimum(f, 1 - f) > margin_uv).all(axis=1)).reshape(H, n, W, n).all(axis=(1, 3))
    return ok


def relative_errors(got, ref, mask, floor=1e-3):
    """Per-pixel relative error against the reference, with the denominator floored at ``floor`` × the image's peak."""
    floor = floor * np.abs(ref[mask]).max()
    rel = np.abs(got - ref).max(axis=-1) / np.maximum(np.abs(ref).max(axis=-1), floor)
    return rel[mask]


def random_scene(rng, model_name, cfg, shape="plane") -> str:
    cam = rng.uniform([-1.5, -2.5, 1.0], [1.5, -1.0, 2.5])
    lights = []
    for _ in range(rng.integers(1, 4)):
        if rng.random() < 0.5:
            p = rng.uniform([-2, -2, 0.5], [2, 2, 3])
            lights.append(f"{{type: point, position: {p.tolist()}, intensity: {rng.uniform(1, 8):.3f}, "
                          f"falloff: {str(bool(rng.random() < 0.7)).lower()}}}")
        else:
            d = rng.uniform([-1, -1, 0.2], [1, 1, 1])
            lights.append(f"{{type: directional, direction: {d.tolist()}, irradiance: {rng.uniform(0.2, 2):.3f}}}")
    obj = ("{shape: plane, size: [2, 2], material: m}" if shape == "plane" else
           "{shape: sphere, radius: 0.8, segments: [256, 128], material: m, transform: {rotate_deg: [10, 20, 30]}}")
    return f"""
camera: {{position: {cam.tolist()}, look_at: [0, 0, 0], fov_deg: 50, resolution: [96, 72]}}
materials: {{m: {{artifact: input}}}}
objects: [{obj}]
lights: [{', '.join(lights)}]
"""


def random_material(rng, model, texels=(4, 4), filter="nearest") -> mat.SceneMaterial:
    """Per-texel random parameters within each parameter's typical range."""
    T = texels[0] * texels[1]
    x = model.pack(model.random_guess(rng, T))
    return mat.SceneMaterial("m", model, x.reshape(texels[1], texels[0], -1).astype(np.float32), None, filter)


MODEL_CASES = [pytest.param(n, c, id=f"{n}-" + "-".join(f"{k}={v}" for k, v in c.items()))
               for n in REGISTRY.names("brdf-model") for c in CONFIGS.get(n, [{}])
               if n not in ("separable",)]


@pytest.mark.parametrize("name,cfg", MODEL_CASES)
def test_gl_matches_cpu_per_pixel_for_every_model(gl, name, cfg):
    """Random camera, 1–3 random point/directional lights, random per-texel parameters: nearest lookups,
    pixels away from texel edges and silhouettes.

    On the plane both renderers see the same geometry, so the bound is float32 against float64.  The GPU's
    sphere is 256×128 facets with interpolated normals (normals off by ~1e-4 rad), so there the denominator is
    floored at 1 % of the peak: the terminator, where the cosine is tiny, is otherwise all relative error."""
    model = REGISTRY.create("brdf-model", name, cfg)
    rng = np.random.default_rng(zlib.crc32(f"{name}{cfg}".encode()))  # str hashes vary between processes
    for shape in ("plane", "sphere"):
        scene = load_scene(random_scene(rng, name, cfg, shape))
        materials = {"m": random_material(rng, model)}
        ref, _ = render_scene(scene, materials)
        got, _ = draw_gl(gl, scene, materials)
        mask = interior(scene, materials, margin_uv=0.02, texels=(4, 4))
        assert mask.sum() > 500
        rel = relative_errors(got, ref, mask, floor=1e-3 if shape == "plane" else 1e-2)
        rms, worst = float(np.sqrt(np.mean(rel**2))), float(rel.max())
        print(f"{name} {cfg} {shape}: rel rms {rms:.2e} max {worst:.2e}")
        assert rms < (1e-5 if shape == "plane" else 2e-3) and worst < (1e-4 if shape == "plane" else 3e-2), (rms, worst)
        assert np.isfinite(got).all() and np.isfinite(ref).all()


def test_bilinear_lookups_agree_within_filtering_precision(gl):
    """GL_LINEAR blends with limited sub-texel precision (8 bits on most hardware, llvmpipe too): a smooth map keeps
    the difference to that order."""
    model = REGISTRY.create("brdf-model", "lafortune", {"lobes": 1})
    rng = np.random.default_rng(3)
    scene = load_scene(random_scene(rng, "lafortune", {}, "plane"))
    base = model.pack(model.random_guess(rng, 1))[0]
    ramp = np.linspace(0.9, 1.1, 16)
    maps = (base[None, None, :] * ramp[None, :, None] * ramp[::-1, None, None]).astype(np.float32)
    materials = {"m": mat.SceneMaterial("m", model, maps, None, "bilinear")}
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    rel = relative_errors(got, ref, interior(scene, materials))
    assert np.sqrt(np.mean(rel**2)) < 5e-3 and rel.max() < 0.05


def lambert_plane(falloff=True):
    return load_scene(f"""
camera: {{position: [0.3, -1.2, 1.5], look_at: [0, 0, 0], fov_deg: 60, resolution: [80, 60]}}
materials: {{m: {{model: lambert, params: {{rho_d: [0.25, 0.15, 0.05]}}}}}}
objects: [{{shape: plane, size: [40, 40], material: m}}]
lights: [{{type: point, position: [0.5, 0.2, 1.0], intensity: [4, 4, 4], falloff: {str(falloff).lower()}}}]
antialias: 1  # the closed form is evaluated at pixel centres
""")


@pytest.mark.parametrize("falloff", [True, False])
def test_lambertian_plane_under_a_point_light_matches_the_closed_form(gl, registry, falloff):
    """L = ρ_d · I · cos θ / d² (ρ_d = albedo/π), at every pixel, on both renderers."""
    scene = lambert_plane(falloff)
    materials = mat.resolve(scene, None, registry)
    dirs, origin = scene.camera.rays()
    hits, which = cast(scene, materials, dirs.reshape(-1, 3), origin)
    d = np.array([0.5, 0.2, 1.0]) - hits.position
    r = np.linalg.norm(d, axis=1)
    expect = np.array([0.25, 0.15, 0.05]) * (4 * d[:, 2] / r / (r**2 if falloff else 1.0))[:, None]
    expect = expect.reshape(60, 80, 3)
    assert (which >= 0).all()
    cpu, _ = render_scene(scene, materials)
    np.testing.assert_allclose(cpu, expect, rtol=1e-7)  # ρ_d is stored as float32
    got, _ = draw_gl(gl, scene, materials)
    np.testing.assert_allclose(got, expect, rtol=1e-4, atol=1e-6)


def test_renders_are_deterministic(gl, registry):
    scene = load_scene(random_scene(np.random.default_rng(9), "lafortune", {}, "sphere"))
    materials = {"m": random_material(np.random.default_rng(1), REGISTRY.create("brdf-model", "lafortune", {"lobes": 2}))}
    a, _ = draw_gl(gl, scene, materials)
    b, _ = draw_gl(gl, scene, materials)
    assert a.tobytes() == b.tobytes()
    c, _ = render_scene(scene, materials)
    d, _ = render_scene(scene, materials)
    assert c.tobytes() == d.tobytes()


def test_shaders_contain_only_what_the_scene_uses(gl):
    from sbrdf_render.gl import fragment_source

    iso = REGISTRY.create("brdf-model", "lafortune", {"lobes": 1})
    aniso = REGISTRY.create("brdf-model", "lafortune", {"lobes": 3, "anisotropic": True, "beta": True})
    scene = load_scene("""
camera: {position: [0, -2, 2]}
objects: [{shape: plane, material: m}]
materials: {m: {artifact: input}}
lights: [{type: point, position: [1, 1, 1]}, {type: point, position: [0, 1, 1]}]
""")
    src = fragment_source(mat.SceneMaterial("m", iso, np.zeros((1, 1, iso.size), np.float32), None, "nearest"),
                          scene.features({"m": mat.SceneMaterial("m", iso, None, None, "nearest")}))
    for absent in ("v_tangent", "beta = ", "cos(beta)", "c_y", "u_dir_", "sampler2DShadow", "discard", "env", "u_alpha",
                   "abs(c)", "u_point_falloff"):
        assert absent not in src, absent
    assert "u_point_pos[2]" in src and src.count("brdf_lafortune(wi, wo") == 2  # two lights, unrolled
    assert "vec3[1](" in src  # one lobe
    m3 = mat.SceneMaterial("m", aniso, np.zeros((1, 1, aniso.size), np.float32), np.ones((1, 1), np.float32), "nearest")
    scene3 = load_scene("""
camera: {position: [0, -2, 2]}
objects: [{shape: plane, material: m}]
materials: {m: {artifact: input}}
lights: [{type: directional, direction: [0, 0, 1]}, {type: point, position: [0, 1, 1], falloff: false}]
shadows: true
""")
    src3 = fragment_source(m3, scene3.features({"m": m3}))
    for present in ("v_tangent", "cos(beta)", "vec3[3](", "u_dir_dir[1]", "sampler2DShadow", "discard", "u_alpha"):
        assert present in src3, present
    assert "/ r2" not in src3  # the only point light has no fall-off
    kurt = REGISTRY.create("brdf-model", "kurt-transmissive", {"lobes": 1, "transmission_lobes": 1})
    mk = mat.SceneMaterial("m", kurt, np.zeros((1, 1, kurt.size), np.float32), None, "nearest")
    assert "abs(c)" in fragment_source(mk, scene.features({"m": mk}))  # transmission only where a model transmits


def test_anisotropic_frames_follow_uv_handedness_on_a_mirrored_mesh(gl, tmp_path):
    """Two quads meeting at a mirror seam (u runs +x on the left, −x on the right; v along +y on both): the tangent
    flips, the handedness w = −1 keeps B = w·N×T along +v, and the CPU and GL frames (hence an anisotropic BRDF)
    agree on both halves."""
    obj = tmp_path / "mirrored.obj"
    obj.write_text("v -1 -1 0\nv 0 -1 0\nv 0 1 0\nv -1 1 0\nv 1 -1 0\nv 1 1 0\n"
                   "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 1 0\nvt 1 1\n"
                   "f 1/1 2/2 3/3 4/4\nf 2/5 5/1 6/4 3/6\n")  # the seam's corners are split, as exporters do
    pos, uv, nrm, idx = load_obj(str(obj))
    normals, tangents = vertex_frames(pos, uv, idx)
    left = np.arange(len(pos)) < 4  # the first face's corners
    assert (tangents[left, 0] > 0.99).all() and (tangents[~left, 0] < -0.99).all()
    assert (tangents[left, 3] == 1).all() and (tangents[~left, 3] == -1).all()
    bitangent = tangents[:, 3:4] * np.cross(normals, tangents[:, :3])
    np.testing.assert_allclose(bitangent, np.tile([0.0, 1.0, 0.0], (len(pos), 1)), atol=1e-12)
    model = REGISTRY.create("brdf-model", "ward", {"anisotropic": True})
    scene = load_scene(f"""
camera: {{position: [0.2, -1.5, 1.8], look_at: [0, 0, 0], fov_deg: 60, resolution: [96, 72]}}
materials: {{m: {{model: ward, model_params: {{anisotropic: true}},
               params: {{rho_d: 0.05, rho_s: 0.4, alpha_x: 0.08, alpha_y: 0.4}}}}}}
objects: [{{shape: mesh, file: {obj}, material: m}}]
lights: [{{type: point, position: [0.3, 0.8, 1.2], intensity: 3}}]
""")
    materials = {"m": mat.uniform("m", model, {"rho_d": 0.05, "rho_s": 0.4, "alpha_x": 0.08, "alpha_y": 0.4})}
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    rel = relative_errors(got, ref, interior(scene, materials))
    assert np.sqrt(np.mean(rel**2)) < 1e-3


def test_obj_loader_fans_polygons_and_reports_malformed_lines(tmp_path):
    good = tmp_path / "quad.obj"
    good.write_text("# a quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf -4 -3 -2 -1\n")
    pos, uv, nrm, idx = load_obj(str(good))
    assert idx.shape == (2, 3) and uv is None and nrm is None and len(pos) == 4
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 x\n")
    with pytest.raises(SbrdfError, match=r"bad.obj:4: malformed OBJ line"):
        load_obj(str(bad))
    missing = tmp_path / "missing.obj"
    missing.write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(SbrdfError, match="vertex that does not exist"):
        load_obj(str(missing))


def test_transmissive_pane_lit_from_behind(gl):
    """A two-sided (transmissive) model shows a light behind the pane; an opaque one stays black."""
    text = """
camera: {position: [0, -1.2, 1.5], look_at: [0, 0, 0], fov_deg: 50, resolution: [64, 48]}
materials: {m: {artifact: input}}
objects: [{shape: plane, size: [2, 2], material: m}]
lights: [{type: point, position: [0.2, 0.3, -1.0], intensity: 5}]
"""
    scene = load_scene(text)
    kurt = REGISTRY.create("brdf-model", "kurt-transmissive", {"lobes": 1, "transmission_lobes": 1})
    params = {p.name: p.default for p in kurt.parameters}
    params.update({k: 0.3 for k in params if k.startswith("m_")})
    params.update({k: [0.8, 0.8, 0.8] for k in params if k.startswith("k_t")})
    materials = {"m": mat.uniform("m", kurt, params)}
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    mask = interior(scene, materials)
    assert ref[mask].max() > 0
    rel = relative_errors(got, ref, mask)
    assert np.sqrt(np.mean(rel**2)) < 1e-3
    opaque = {"m": mat.uniform("m", REGISTRY.create("brdf-model", "lambert", {}), {"rho_d": 0.3})}
    assert render_scene(scene, opaque)[0].max() == 0


def test_shadows_match_the_reference_away_from_edges(gl, registry):
    scene = load_scene("""
camera: {position: [0, -2.2, 2.0], look_at: [0, 0, 0.2], fov_deg: 45, resolution: [96, 72]}
materials: {m: {model: lambert, params: {rho_d: 0.2}}}
objects:
  - {shape: plane, size: [3, 3], material: m}
  - {shape: sphere, radius: 0.35, material: m, transform: {translate: [0, 0, 0.5]}}
lights: [{type: point, position: [0.8, 0.5, 2.5], intensity: 6}, {type: directional, direction: [-1, 0, 1], irradiance: 0.4}]
shadows: true
""")
    materials = mat.resolve(scene, None, registry)
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    unshadowed, _ = render_scene(scene.__class__(**{**scene.__dict__, "shadows": False}), materials)
    mask = interior(scene, materials)
    shadowed = mask & (ref.sum(-1) < 0.9 * unshadowed.sum(-1))
    assert shadowed.sum() > 100  # the sphere casts shadows from both lights
    rel = relative_errors(got, ref, mask)
    # all but the pixels along shadow edges (1 % point-sampled; 1.5 % with the default 2×2 antialiasing, whose
    # partly shadowed pixels widen the edges)
    assert np.mean(rel < 1e-3) > 0.98


def test_alpha_kill_shows_what_is_behind(gl):
    scene = load_scene("""
camera: {position: [0, -1.5, 2], look_at: [0, 0, 0], fov_deg: 50, resolution: [64, 48]}
materials: {front: {artifact: input}, back: {model: lambert, params: {rho_d: [0, 0.3, 0]}}}
objects:
  - {shape: plane, size: [2, 2], material: front, transform: {translate: [0, 0, 0.3]}}
  - {shape: plane, size: [4, 4], material: back}
lights: [{type: directional, direction: [0, 0, 1], irradiance: 1}]
""")
    lam = REGISTRY.create("brdf-model", "lambert", {})
    alpha = np.array([[1.0, 0.0], [0.0, 1.0]], np.float32)  # a checkerboard of holes
    front = mat.SceneMaterial("front", lam, np.full((2, 2, 3), [0.3, 0, 0], np.float32), alpha, "nearest")
    materials = {"front": front, "back": mat.uniform("back", lam, {"rho_d": [0, 0.3, 0]})}
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    red, green = (ref[..., 0] > 0).sum(), (ref[..., 1] > 0).sum()
    assert red > 200 and green > 200
    mask = interior(scene, materials, margin_uv=0.05, texels=(2, 2))
    rel = relative_errors(got, ref, mask)
    assert np.mean(rel < 1e-4) > 0.98


# -- hard cases -------------------------------------------------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(elev=st.floats(0.0, 1.0), light_elev=st.floats(-0.2, 1.0), exponent=st.floats(1.0, 1e4),
       cx=st.floats(-1.5, 1.5))
def test_cpu_shading_is_finite_at_grazing_angles_and_huge_exponents(elev, light_elev, exponent, cx):
    """Camera and light from the horizon to the zenith, exponents to 10⁴, |C_x| > C_z: finite, non-negative."""
    cam = [0.0, float(-2.0 * np.cos(elev * np.pi / 2)), float(2.0 * np.sin(elev * np.pi / 2) + 1e-3)]
    scene = load_scene(f"""
camera: {{position: {cam}, look_at: [0, 0, 0], up: [1, 0, 0], fov_deg: 30, resolution: [16, 12]}}
materials: {{m: {{model: lafortune, params: {{rho_d: 0.1, rho_s_1: 2.0, c_xy_1: {cx:.12f}, c_z_1: 1.0, exponent_1: {exponent:.9f}}}}}}}
objects: [{{shape: plane, size: [4, 4], material: m}}]
lights: [{{type: directional, direction: [0, 1, {light_elev:.12f}], irradiance: 1}}]
""")
    model = REGISTRY.create("brdf-model", "lafortune", {"lobes": 1})
    materials = {"m": mat.uniform("m", model, {"rho_d": 0.1, "rho_s_1": 2.0, "c_xy_1": cx, "c_z_1": 1.0,
                                               "exponent_1": exponent})}
    image, _ = render_scene(scene, materials)
    assert np.isfinite(image).all() and (image >= 0).all()


# -- scene files --------------------------------------------------------------------------------------------------------


def test_scene_errors_name_the_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("""camera: {position: [0, -2, 2], fov_deg: 400}
materials: {m: {artifact: input}}
objects:
  - {shape: cube, material: m}
  - {shape: sphere, radius: -1, material: nope}
  - {shape: mesh, file: missing.obj, material: m}
lights:
  - {type: spot, position: [0, 0, 1]}
  - {type: point, intensity: [1, 2]}
colour: red
""")
    with pytest.raises(SceneError) as e:
        load_scene(str(path))
    text = str(e.value)
    for line, what in ((1, "fov_deg"), (4, "cube"), (5, "radius"), (5, "nope"), (6, "missing.obj"), (8, "spot"),
                       (9, "position"), (10, "colour")):
        assert f"bad.yaml:{line}:" in text and what in text, (line, what, text)


def test_scene_needs_a_light_and_valid_materials():
    with pytest.raises(SceneError, match="no light"):
        load_scene("camera: {}\nobjects: [{shape: plane}]\nmaterials: {sample: {artifact: input}}\n")
    with pytest.raises(SceneError, match="either artifact"):
        load_scene("objects: [{shape: plane, material: m}]\nmaterials: {m: {}}\nlights: [{type: directional, "
                   "direction: [0, 0, 1]}]\n")


def test_uniform_material_rejects_unknown_and_out_of_bounds_parameters():
    lam = REGISTRY.create("brdf-model", "lambert", {})
    with pytest.raises(SbrdfError, match="unknown parameter"):
        mat.uniform("m", lam, {"albedo": 0.5})
    with pytest.raises(SbrdfError, match="outside its bounds"):
        mat.uniform("m", lam, {"rho_d": -1})


def test_tessellated_shapes_agree_with_the_ray_caster():
    """Vertex attributes of the GPU meshes equal the CPU's analytic surface attributes at the same points."""
    from sbrdf_lib.surface import intersect

    scene = load_scene("""
objects:
  - {shape: sphere, radius: 0.7, segments: [32, 16], transform: {translate: [0.1, 0.2, 0.3], rotate_deg: [20, 0, 40]}}
  - {shape: cylinder, radius: 0.4, height: 1.2, segments: 24, transform: {scale: 2}}
materials: {sample: {artifact: input}}
lights: [{type: directional, direction: [0, 0, 1]}]
""")
    for obj in scene.objects:
        mesh = tessellate(obj)
        keep = (mesh.uvs[:, 1] > 0.01) & (mesh.uvs[:, 1] < 0.99) & (np.abs(mesh.uvs[:, 0] - 0.5) < 0.499)  # poles, seam
        target = mesh.positions[keep]
        origin = target + mesh.normals[keep] * 0.5
        hits = intersect(obj, origin, -mesh.normals[keep])[0]
        np.testing.assert_allclose(hits.position, target, atol=1e-9)
        np.testing.assert_allclose(hits.normal, mesh.normals[keep], atol=1e-9)
        np.testing.assert_allclose(hits.tangent, mesh.tangents[keep], atol=1e-9)
        np.testing.assert_allclose(hits.uv, mesh.uvs[keep], atol=1e-9)


# -- the Render node in a graph ----------------------------------------------------------------------------------------


def test_render_nodes_in_a_graph_write_exr_and_png(gl, tmp_path, write_graph, registry):
    from sbrdf_core.graph import load_graph
    from sbrdf_core.io import read_exr
    from sbrdf_core.runner import Runner

    (tmp_path / "scene.yaml").write_text("""
camera: {position: [0, -1.5, 1.5], look_at: [0, 0, 0], fov_deg: 45, resolution: [64, 48]}
objects:
  - {shape: plane, size: [1.5, 1.5]}
  - {shape: sphere, radius: 0.3, transform: {translate: [0, 0, 0.3]}}
lights: [{type: point, position: [1, -1, 2], intensity: 5}]
""")
    graph = tmp_path / "g.yaml"
    graph.write_text(f"""
name: render
store: {tmp_path / 'runs'}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [16, 16], poses: 24, model: lambert, seed: 2}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lambert}}}}
  gl: {{kind: Render, plugin: gl, in: {{material: fit}}, params: {{scene: scene.yaml, frames: 2}}}}
  cpu: {{kind: Render, plugin: cpu, in: {{material: fit}}, params: {{scene: scene.yaml}}}}
""")
    Runner(registry).run(load_graph(str(graph), registry))
    images = {}
    for node in ("gl", "cpu"):
        out = tmp_path / "runs" / node
        assert (out / "image.png").exists()
        images[node] = read_exr(str(out / "image.exr"))
    assert images["gl"].shape == (48, 64, 3) and images["gl"].max() > 0
    rel = np.abs(images["gl"] - images["cpu"]).max(-1) / np.maximum(images["cpu"].max(-1), 1e-3 * images["cpu"].max())
    assert np.median(rel) < 1e-4
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(scene_file.read_text().replace("resolution: [64, 48]", "resolution: [32, 24]"))
    report = Runner(registry).run(load_graph(str(graph), registry))  # an edited scene re-renders; the fit is cached
    assert read_exr(str(tmp_path / "runs" / "cpu" / "image.exr")).shape == (24, 32, 3)
    assert report["fit"].status == "cached" and report["cpu"].status == "computed"
    bad = tmp_path / "bad.yaml"
    bad.write_text(graph.read_text().replace("scene.yaml}", "nowhere.yaml}"))
    with pytest.raises(GraphError, match="cannot read scene file"):
        load_graph(str(bad), registry)


def test_large_meshes_are_not_clipped(gl, tmp_path):
    """Clip planes come from the vertices, so a mesh far larger than the unit sphere is drawn whole."""
    obj = tmp_path / "floor.obj"
    obj.write_text("v -20 -20 0\nv 20 -20 0\nv 20 20 0\nv -20 20 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n")
    scene = load_scene(f"""
camera: {{position: [0, -8, 3], look_at: [0, 6, 0], fov_deg: 60, resolution: [64, 48]}}
materials: {{m: {{model: lambert, params: {{rho_d: 0.2}}}}}}
objects: [{{shape: mesh, file: {obj}, material: m}}]
lights: [{{type: directional, direction: [0, 0, 1], irradiance: 1}}]
""")
    materials = {"m": mat.uniform("m", REGISTRY.create("brdf-model", "lambert", {}), {"rho_d": 0.2})}
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    assert (ref.sum(-1) > 0).mean() > 0.4
    assert abs((got.sum(-1) > 0).mean() - (ref.sum(-1) > 0).mean()) < 0.02
    # the scene's bounding sphere (mirror pass, shadow maps) covers the mesh's vertices, scale included
    scaled = load_scene(f"""
camera: {{position: [0, -8, 3], look_at: [0, 6, 0], fov_deg: 60, resolution: [64, 48]}}
materials: {{m: {{model: lambert, params: {{rho_d: 0.2}}}}}}
objects: [{{shape: mesh, file: {obj}, material: m, transform: {{translate: [1, 2, 0], scale: 2}}}}]
lights: [{{type: directional, direction: [0, 0, 1], irradiance: 1}}]
""")
    centre, radius = scaled.bounds()
    np.testing.assert_allclose(centre, [1, 2, 0])
    assert radius == pytest.approx(2 * 20 * np.sqrt(2))


def test_separable_model_renders_with_its_factor_textures(gl):
    """A fitted separable BRDF (Kautz & McCool) binds its factor textures: gl agrees with the cpu's factor lookups."""
    from sbrdf_separable.decompose import nd, parameterization
    from sbrdf_separable.sources import model_function

    ward = REGISTRY.create("brdf-model", "ward", {"anisotropic": True})
    fn = model_function(ward, {"rho_d": [0.3, 0.1, 0.05], "rho_s": [0.3] * 3, "alpha_x": [0.21], "alpha_y": [0.1]})
    model = REGISTRY.create("brdf-model", "separable", {})
    model.set_factors(nd(fn, parameterization("gram-schmidt"), 16, terms=2, clamp_max=5.0))
    scene = load_scene(random_scene(np.random.default_rng(5), "separable", {}, "plane"))
    materials = {"m": mat.uniform("m", model, {"scale": [1.0, 1.0, 1.0]})}
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    rel = relative_errors(got, ref, interior(scene, materials), floor=1e-2)
    assert ref.max() > 0 and np.sqrt(np.mean(rel**2)) < 5e-3


def _preview_of_bright_bottom_half(texels=(8, 6)):
    """A Lambertian material twice as bright at v < V/2 as above, drawn by ``preview``."""
    import dask.array as da

    from sbrdf_core.types import Material
    from sbrdf_render.preview import PreviewRenderer

    U, V = texels
    rho = np.full((V, U, 3), 0.2, np.float32)
    rho[: V // 2] = 0.4  # array row = texel row v
    model = REGISTRY.create("brdf-model", "lambert", {})
    material = Material(model, {"rho_d": da.from_array(rho, chunks=(4, 4, 3))}, texels, (40.0, 30.0), "test")
    return np.asarray(PreviewRenderer(light_pos_mm=[300.0, 0.0, 520.0], camera_pos_mm=[0.0, 0.0, 800.0]).render(material).image.compute())


def test_preview_draws_v0_at_the_bottom_like_the_camera_and_sbrdf_plot():
    """Image row 0 is the top (highest v): a material bright at low v is bright in the last rows."""
    img = _preview_of_bright_bottom_half()
    assert img.shape == (6, 8, 3)
    lum = img.mean(axis=(1, 2))
    assert lum[3:].min() > 1.5 * lum[:3].max()  # bottom rows (v = 0..2) bright, top rows (v = 3..5) dim


def test_preview_png_written_by_the_render_node_is_v_up(tmp_path, registry):
    """Through a graph: the PNG's bottom rows show texel row v = 0 of the fitted material."""
    from sbrdf_core.graph import load_graph
    from sbrdf_core.io import read_png
    from sbrdf_core.runner import Runner
    from sbrdf_core.store import open_artifact

    graph = tmp_path / "g.yaml"
    graph.write_text(f"""
name: preview-orientation
store: {tmp_path / 'runs'}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [16, 8], poses: 12, model: lambert, seed: 2}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lambert}}}}
  render: {{kind: Render, plugin: preview, in: {{material: fit}}}}
""")
    Runner(registry).run(load_graph(str(graph), registry))
    rho = open_artifact(str(tmp_path / "runs" / "fit")).read("params/rho_d").mean(-1)  # (V, U), row = v
    png = read_png(str(tmp_path / "runs" / "render" / "image.png")).astype(float).mean(-1)
    stored = open_artifact(str(tmp_path / "runs" / "render")).read("image").mean(-1)
    assert png.shape == rho.shape == stored.shape

    def corr(a, b):
        return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])

    # the texture is not symmetric in v (a checker two squares high), so only one orientation matches it
    assert np.abs(rho - rho[::-1]).mean() > 0.2 * rho.mean()
    for image in (png, stored):
        assert corr(image, rho[::-1]) > 0.8 > corr(image, rho) + 0.3


# -- antialiasing ------------------------------------------------------------------------------------------------------


def checker_scene(antialias: int) -> str:
    """A high-contrast 8×8 checker (nearest) on a plane seen obliquely and on a sphere: many texel edges."""
    return f"""
camera: {{position: [0.4, -1.6, 1.1], look_at: [0, 0, 0.1], fov_deg: 50, resolution: [48, 36]}}
materials: {{m: {{artifact: input}}}}
objects:
  - {{shape: plane, size: [2, 2], material: m, uv_repeat: [2, 2]}}
  - {{shape: sphere, radius: 0.3, segments: [256, 128], material: m, transform: {{translate: [0.3, 0.2, 0.35]}}}}
lights: [{{type: point, position: [1, -1, 2], intensity: 6}}, {{type: directional, direction: [-1, -0.3, 1], irradiance: 0.5}}]
antialias: {antialias}
"""


def checker_material(filter="nearest") -> mat.SceneMaterial:
    model = REGISTRY.create("brdf-model", "lambert", {})
    check = (np.add.outer(np.arange(8), np.arange(8)) % 2).astype(np.float32)
    rho = 0.02 + 0.9 * check  # 45:1 contrast
    return mat.SceneMaterial("m", model, np.repeat(rho[..., None], 3, -1), None, filter)


def test_antialias_key_defaults_to_4_and_takes_squares_only():
    base = checker_scene(1).replace("antialias: 1\n", "")
    assert load_scene(base).antialias == 4 and load_scene(base).subpixels == 2
    assert load_scene(base + "antialias: 1\n").supersampled().camera.resolution == (48, 36)
    assert load_scene(base + "antialias: 9\n").supersampled().camera.resolution == (144, 108)
    for bad in ("2", "0", "true", "4.0", "100", "[2, 2]"):
        with pytest.raises(SceneError, match=r"<scene>:8: antialias must be .* square"):
            load_scene(base + f"antialias: {bad}\n")


def test_antialiasing_brings_texel_edges_towards_a_supersampled_reference(gl):
    """Edge pixels (where the checker's texel changes inside the pixel): the default 2×2 supersampling is much
    closer to an 8×8 reference than point sampling (measured: mean error 0.54 → 0.18 of the reference's mean),
    and both renderers antialias alike (they sample the same sub-pixel points)."""
    from sbrdf_render.cpu import texel_edges

    materials = {"m": checker_material()}
    ref, _ = render_scene(load_scene(checker_scene(64)), materials)
    point, _ = render_scene(load_scene(checker_scene(1)), materials)
    scene = load_scene(checker_scene(4))
    aa, stats = render_scene(scene, materials)
    assert stats["antialias"] == 4
    edges = texel_edges(scene, materials)
    assert edges.sum() > 100

    def err(img):
        return float(np.abs(img - ref)[edges].mean() / np.abs(ref[edges]).mean())

    e_point, e_aa = err(point), err(aa)
    print(f"edge error: point-sampled {e_point:.3f}, 2×2 {e_aa:.3f}")
    assert e_aa < 0.6 * e_point, (e_point, e_aa)
    inside = interior(scene, materials) & ~texel_edges(scene, materials, 2)  # 2×2: the pixels' own sub-samples
    # inside texels antialiasing changes little: lighting varies slowly across a pixel
    assert np.abs(aa - point)[inside].mean() < 0.01 * np.abs(point[inside]).mean()

    got, _ = draw_gl(gl, scene, materials)  # gl against cpu, antialiasing on, edge pixels included
    mask = interior(scene, materials, margin_uv=1e-4, texels=(16, 16))  # no sub-sample within float32 of an edge
    assert (mask & edges).sum() > 50
    rel = relative_errors(got, aa, mask, floor=1e-2)
    assert np.sqrt(np.mean(rel**2)) < 2e-3 and rel.max() < 3e-2, (np.sqrt(np.mean(rel**2)), rel.max())


def test_gl_plugin_antialiases_the_geforce4_path_like_the_float_path(gl, registry, tmp_path):
    """The Render plugins honour antialias: both gl pipelines return the scene's resolution, antialiased."""
    from sbrdf_render.gl import GLRenderer

    scene = tmp_path / "s.yaml"
    scene.write_text(checker_scene(4).replace("materials: {m: {artifact: input}}",
                                              "materials: {m: {model: lafortune}}"))
    r = GLRenderer(scene=str(scene), pipeline="geforce4")
    r.bind(registry)
    out = r.render(None)
    assert out.image.shape[:2] == (36, 48) and out.attrs["antialias"] == 4


def test_gl_refuses_a_supersampled_framebuffer_beyond_the_driver_limit(gl):
    scene = load_scene(checker_scene(64).replace("resolution: [48, 36]", "resolution: [4096, 8]"))
    with pytest.raises(SbrdfError, match=r"framebuffer would be 32768×64 .* lower antialias"):
        gl.GLScene(scene, {"m": checker_material()})


# -- plugins' scene keys and renderable kinds (issue 22) -----------------------------------------------------------

PLUGIN_KEYS_SCENE = """
camera: {resolution: [8, 6]}
materials: {m: {model: lambert, params: {rho_d: 0.5}}}
objects: [{shape: plane, material: m, reflector: false}]
lights: [{type: directional, direction: [0, 0, 1]}]
"""


def test_scene_keys_come_from_the_plugins_that_read_them(registry):
    """``reflector:`` (sbrdf_envmap) and ``shading_map:`` (sbrdf_shading) exist only with their plugin."""
    from sbrdf_core.registry import Registry
    from sbrdf_lib.scene import plugin_keys

    keys = plugin_keys(registry)
    assert "environment" in keys.sections and "reflector" in {p.name for p in keys.shapes["plane"]}
    assert "shading_map" in {p.name for p in keys.material_params}
    load_scene(PLUGIN_KEYS_SCENE, registry=registry)
    with pytest.raises(SceneError, match="reflector"):
        load_scene(PLUGIN_KEYS_SCENE, registry=Registry(disabled=["envmap"]))
    text = PLUGIN_KEYS_SCENE.replace("params: {rho_d: 0.5}", "params: {rho_d: 0.5}, shading_map: input")
    assert load_scene(text, registry=registry).materials["m"].surface["options"] == {
        "variant": "r", "above_max": "clamp", "sigma": 1.0}
    with pytest.raises(SceneError, match="shading_map"):
        load_scene(text, registry=Registry(disabled=["shading"]))


def test_the_render_port_accepts_the_kinds_plugins_declare_renderable(registry):
    from sbrdf_core.artifacts import KINDS
    from sbrdf_core.nodes.render import Render

    port = Render.inputs[0]
    assert {"ParamMaps", "TextureSet", "ShadingMap", "PowerShadingMap"} <= set(port.names)
    assert all(KINDS[n].material for n in port.names if n not in ("ParamMaps", "TextureSet"))


def test_a_renderers_prepare_step_gives_what_render_would_compute(registry):
    """Build never computes: ``prepare(material)`` lists the maps, and ``render(prepared=)`` uses them as given."""
    import dask
    import dask.array as da

    from sbrdf_core.types import Material
    from sbrdf_render.cpu import CPURenderer

    model = registry.create("brdf-model", "lambert", {})
    rho = np.random.default_rng(0).uniform(0.1, 0.9, (6, 8, 3)).astype(np.float32)
    material = Material(model, {"rho_d": da.from_array(rho, chunks=(3, 4, 3))}, (8, 6), (40.0, 30.0), "test")
    r = CPURenderer(scene=checker_scene(1).replace("resolution: [48, 36]", "resolution: [12, 9]"))
    r.bind(registry)
    lazy = r.prepare(material)
    assert sorted(lazy) == ["m/params/rho_d"] and all(dask.is_dask_collection(v) for v in lazy.values())
    computed = dask.compute(lazy)[0]
    assert np.array_equal(r.render(material, prepared=computed).image, r.render(material).image)
