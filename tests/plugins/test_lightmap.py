"""Light maps (sbrdf_lightmap, Mühlbacher §4.3): the bake against the cpu renderer and a Monte Carlo reference,
the renderers' k_d/pi E (Eq 4.1) in cpu and gl, the scene keys' validation."""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_core.io import write_exr
from sbrdf_core.registry import default_registry
from sbrdf_lib import lightmap as lmlib
from sbrdf_lib.scene import SceneError, load_scene
from sbrdf_lib.surface import cast
from sbrdf_lightmap.bake import bake, cosine_rays, rho_d
from sbrdf_render import materials as mat
from sbrdf_render.cpu import render_scene

REGISTRY = default_registry()

#: A closed diffuse box (a room: floor, ceiling, four walls facing in, one wall red) with a ball, under a point light.
BOX = """
camera: {{position: [0.0, -0.9, 1.1], look_at: [0.0, 0.5, 0.6], fov_deg: 70, resolution: [32, 24]}}
antialias: 1
materials:
  white: {{model: lambert, params: {{rho_d: 0.2}}}}
  red: {{model: lambert, params: {{rho_d: [0.25, 0.05, 0.05]}}}}
  ball: {{model: lambert, params: {{rho_d: [0.05, 0.2, 0.05]}}}}
objects:
  - {{shape: plane, size: [2, 2], material: white}}
  - {{shape: plane, size: [2, 2], material: white, transform: {{translate: [0, 0, 2], rotate_deg: [180, 0, 0]}}}}
  - {{shape: plane, size: [2, 2], material: red, transform: {{translate: [-1, 0, 1], rotate_deg: [0, 90, 0]}}}}
  - {{shape: plane, size: [2, 2], material: white, transform: {{translate: [1, 0, 1], rotate_deg: [0, -90, 0]}}}}
  - {{shape: plane, size: [2, 2], material: white, transform: {{translate: [0, 1, 1], rotate_deg: [90, 0, 0]}}}}
  - {{shape: plane, size: [2, 2], material: white, transform: {{translate: [0, -1, 1], rotate_deg: [-90, 0, 0]}}}}
  - {{shape: sphere, radius: 0.3, material: ball, transform: {{translate: [0.2, 0.3, 0.3]}}}}
lights:
  - {{type: point, position: [0.0, 0.0, 1.7], intensity: 2.0}}
shadows: true
{lightmap}
"""


def box(tmp_path, bounces=1, size=16, samples=32, extra=""):
    text = BOX.format(lightmap=f"lightmap: {{directory: {tmp_path / 'lm'}, size: {size}, bounces: {bounces}, "
                               f"samples: {samples}{extra}}}")
    return load_scene(text)


def baked(scene):
    materials = mat.resolve(scene, None, REGISTRY)
    maps, stats = bake(scene, materials)
    for k, E in maps.items():
        write_exr(lmlib.map_path(scene.lightmap.directory, k), E)
    return materials, maps, stats


def direct_irradiance(scene, materials, p, n, meshes):
    """E of the point lights at points p with normals n, with shadow rays: the cpu renderer's Eq 6.3 terms."""
    E = np.zeros((len(p), 3))
    o = p + 1e-5 * n
    for light in scene.lights:
        d = light.vector - p
        dist = np.linalg.norm(d, axis=1)
        w = d / dist[:, None]
        c = np.einsum("ij,ij->i", n, w)
        lit = c > 0
        h, _ = cast(scene, materials, w[lit], o[lit], meshes)
        vis = h.t >= dist[lit] * (1 - 1e-6)
        E[lit] += light.power[None] / (dist[lit] ** 2)[:, None] * (c[lit] * vis)[:, None]
    return E


def path_traced(scene, materials, samples=128, seed=1):
    """Monte Carlo reference of direct + one diffuse bounce per pixel: at the pixel's hit, E_direct exactly plus
    π/K Σ ρ_d(y) E_direct(y) over K cosine-distributed rays, E_direct(y) with shadow rays (no light map)."""
    meshes: dict = {}
    dirs, origin = scene.camera.rays()
    H, W = dirs.shape[:2]
    hits, which = cast(scene, materials, dirs.reshape(-1, 3), origin, meshes)
    ok = np.nonzero(which >= 0)[0]
    p, n = hits.position[ok], hits.normal[ok]
    E = direct_irradiance(scene, materials, p, n, meshes)
    rays = cosine_rays(n, samples, np.random.default_rng(seed)).reshape(-1, 3)
    h2, w2 = cast(scene, materials, rays, np.repeat(p + 1e-5 * n, samples, axis=0), meshes)
    front = (w2 >= 0) & (np.einsum("ij,ij->i", h2.normal, rays) < 0)
    L = np.zeros((len(rays), 3))
    for k, obj in enumerate(scene.objects):
        sel = np.nonzero(front & (w2 == k))[0]
        L[sel] = rho_d(materials[obj.material], h2.uv[sel]) * direct_irradiance(
            scene, materials, h2.position[sel], h2.normal[sel], meshes)
    E += np.pi / samples * L.reshape(-1, samples, 3).sum(1)
    img = np.zeros((H * W, 3))
    for k, obj in enumerate(scene.objects):
        sel = which[ok] == k
        img[ok[sel]] = rho_d(materials[obj.material], hits.uv[ok[sel]]) * E[sel]
    return img.reshape(H, W, 3)


def rel_rms(a, b):
    return float(np.sqrt(((a - b) ** 2).mean() / (b ** 2).mean()))


def test_direct_light_map_renders_as_the_cpu_renderers_shadowed_lights(tmp_path):
    """Bounces 0: ρ_d·E(uv) from 16² maps against the cpu renderer's own ρ_d E cos θ with shadow rays.
    Measured rel RMS 0.052 (texel interpolation across shadow edges; 0.029 with 32² maps); mean within 1 %."""
    scene = box(tmp_path, bounces=0)
    materials, maps, stats = baked(scene)
    assert stats["bounces"] == 0 and all(E.shape == (16, 16, 3) for E in maps.values())
    got, _ = render_scene(scene, materials, registry=REGISTRY)
    plain = load_scene(BOX.format(lightmap=""))
    ref, _ = render_scene(plain, mat.resolve(plain, None, REGISTRY), registry=REGISTRY)
    assert rel_rms(got, ref) < 0.08 and abs(got.mean() / ref.mean() - 1) < 0.02


def test_one_bounce_light_map_matches_the_monte_carlo_reference(tmp_path):
    """Bounces 1 against a per-pixel Monte Carlo reference of direct + one bounce (128 rays, exact direct light at
    the secondary hits).  The bounce nearly doubles the image; measured rel RMS 0.065 (16² maps, 32 rays, one smoothing pass: texel
    interpolation and bake noise; 0.083 unsmoothed, 0.050 with 32² maps and 64 rays), mean +0.9 %."""
    scene = box(tmp_path, bounces=1)
    materials, _, _ = baked(scene)
    got, _ = render_scene(scene, materials, registry=REGISTRY)
    ref = path_traced(scene, materials)
    plain = load_scene(BOX.format(lightmap=""))
    direct, _ = render_scene(plain, mat.resolve(plain, None, REGISTRY), registry=REGISTRY)
    assert ref.mean() > 1.5 * direct.mean()  # the bounce matters
    assert rel_rms(got, ref) < 0.12 and abs(got.mean() / ref.mean() - 1) < 0.03


def test_gl_shades_the_light_map_as_cpu(gl, tmp_path):
    """The same maps through GL_LINEAR clamp-to-edge textures (no shadow maps: gl has no cube shadow maps for a
    light inside a room, and a light-mapped Lambertian scene needs none)."""
    scene = load_scene(BOX.format(lightmap=f"lightmap: {{directory: {tmp_path / 'lm'}, size: 16, bounces: 1, "
                                           "samples: 8}").replace("shadows: true", "shadows: false"))
    materials, _, _ = baked(scene)
    ref, _ = render_scene(scene, materials, registry=REGISTRY)
    drawer = gl.GLScene(scene, materials, registry=REGISTRY)
    try:
        got = drawer.draw().image.astype(np.float64)
        assert all("u_lightmap" in fs for _, fs in drawer.sources.values())
    finally:
        drawer.release()
    assert rel_rms(got, ref) < 0.01
    plain = load_scene(BOX.format(lightmap="").replace("shadows: true", "shadows: false"))
    drawer = gl.GLScene(plain, mat.resolve(plain, None, REGISTRY), registry=REGISTRY)
    try:
        assert all("lightmap" not in fs for _, fs in drawer.sources.values())
    finally:
        drawer.release()


def test_area_light_and_environment_bake(tmp_path):
    """An area light of radiance L over a large floor: E at the centre below it = L·(solid-angle cosine integral);
    a white environment alone on an open plane: E = π L everywhere."""
    text = """
camera: {{position: [0, -2, 2], look_at: [0, 0, 0], resolution: [8, 8]}}
materials: {{m: {{model: lambert, params: {{rho_d: 0.1}}}}}}
objects: [{{shape: plane, size: [0.02, 0.02], material: m}}]
{extra}
lightmap: {{directory: {d}, size: 2, bounces: 0, samples: 4096{areas}}}
"""
    areas = ", area_lights: [{position: [0, 0, 1], size: [2, 2], radiance: 3.0}]"
    scene = load_scene(text.format(extra="", d=tmp_path, areas=areas))
    maps, _ = bake(scene, mat.resolve(scene, None, REGISTRY))
    # a square of half-side a at height h, point on the axis: E = L·4·(a/√(a²+h²))·atan(a/√(a²+h²))
    a, h = 1.0, 1.0
    s = a / np.hypot(a, h)
    expected = 3.0 * 4 * s * np.arctan(s)
    np.testing.assert_allclose(maps[0], expected, rtol=0.01)
    env = tmp_path / "white.exr"
    write_exr(str(env), np.full((8, 16, 3), 0.5, np.float32))
    scene = load_scene(text.format(extra=f"environment: {{file: {env}, options: {{size: 4, diffuse_size: 4}}}}",
                                   d=tmp_path, areas=""))
    materials = mat.resolve(scene, None, REGISTRY)
    from sbrdf_lightmap.node import environment

    maps, _ = bake(scene, materials, environment(REGISTRY, scene, materials))
    np.testing.assert_allclose(maps[0], np.pi * 0.5, rtol=1e-6)


def test_lightmap_keys_are_validated(tmp_path):
    with pytest.raises(SceneError, match=r"lightmap: parameter 'size'"):
        box(tmp_path, size=1)
    with pytest.raises(SceneError, match="area light 0: radiance"):
        box(tmp_path, extra=", area_lights: [{position: [0, 0, 1], radiance: -1}]")
    with pytest.raises(SceneError, match="unknown parameter"):
        box(tmp_path, extra=", bounce: 2")
    scene = box(tmp_path)
    with pytest.raises(SbrdfError, match="does not exist; bake the light maps first"):
        render_scene(scene, mat.resolve(scene, None, REGISTRY), registry=REGISTRY)
    off = box(tmp_path, extra=", use: false")  # the section stays, the lights shade again: no maps needed
    assert not off.lightmapped and not off.features().lightmap
    render_scene(off, mat.resolve(off, None, REGISTRY), registry=REGISTRY)


def test_lookup_is_bilinear_clamp_to_edge():
    E = np.arange(2 * 2 * 3, dtype=np.float64).reshape(2, 2, 3)
    np.testing.assert_allclose(lmlib.lookup(E, np.array([[0.25, 0.25], [0.0, 0.0], [1.0, 1.0]])),
                               [E[0, 0], E[0, 0], E[1, 1]])
    np.testing.assert_allclose(lmlib.lookup(E, np.array([[0.5, 0.25]])), [(E[0, 0] + E[0, 1]) / 2])


def test_a_mirror_reflects_the_light_mapped_scene(gl, tmp_path):
    """A glossy floor reflector in the light-mapped box: its mirror pass draws ρ_d·E from the maps (the thesis's
    light-mapped mirror pass), the cpu reference ray-casts the same radiance.  Measured rel RMS 0.044 at 7 samples."""
    text = BOX.format(lightmap=f"lightmap: {{directory: {tmp_path / 'lm'}, size: 16, bounces: 1, samples: 16}}")
    text = text.replace("shadows: true", "shadows: false").replace(
        "  - {shape: plane, size: [2, 2], material: white}\n",
        "  - {shape: plane, size: [2, 2], material: floor, reflector: true}\n").replace(
        "materials:\n", "materials:\n  floor: {model: lafortune, params: {rho_d: 0.1, rho_s_1: 31.8, c_xy_1: -1.0, "
                        "c_z_1: 1.0, exponent_1: 200}}\n") + "mirror: {samples: 7, mc_samples: 128}\n"
    scene = load_scene(text)
    materials, _, _ = baked(scene)
    ref, _ = render_scene(scene, materials, registry=REGISTRY)
    drawer = gl.GLScene(scene, materials, registry=REGISTRY)
    try:
        got = drawer.draw().image.astype(np.float64)
    finally:
        drawer.release()
    assert rel_rms(got, ref) < 0.07 and abs(got.mean() / ref.mean() - 1) < 0.03


# -- generated charts for meshes without UVs ----------------------------------------------------------------------

CUBE_OBJ = ("v -0.2 -0.2 0\nv 0.2 -0.2 0\nv 0.2 0.2 0\nv -0.2 0.2 0\nv -0.2 -0.2 0.4\nv 0.2 -0.2 0.4\nv 0.2 0.2 0.4\n"
            "v -0.2 0.2 0.4\nf 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n")  # no vt, no vn


def test_triangle_atlas_is_a_chart():
    from sbrdf_lib.surface import triangle_atlas

    for n in (1, 2, 3, 12, 101):
        uv = triangle_atlas(n).reshape(n, 3, 2)
        assert (uv > 0).all() and (uv < 1).all()
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        assert (area > 0).all() and area.sum() < 1  # counter-clockwise, no room for overlap
        # no two triangles share a point: sample each triangle's interior and test it against all others
        w = np.random.default_rng(0).dirichlet((1, 1, 1), 32)
        pts = np.einsum("sk,tkd->tsd", w, uv)
        for t in range(n):
            a, b, c = uv[t]
            d = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
            q = np.delete(pts, t, axis=0).reshape(-1, 2)
            l0 = ((b[1] - c[1]) * (q[:, 0] - c[0]) + (c[0] - b[0]) * (q[:, 1] - c[1])) / d
            l1 = ((c[1] - a[1]) * (q[:, 0] - c[0]) + (a[0] - c[0]) * (q[:, 1] - c[1])) / d
            assert not ((l0 > 0) & (l1 > 0) & (1 - l0 - l1 > 0)).any()


def test_mesh_without_uvs_gets_a_chart_and_its_light_map_renders_as_the_lights(tmp_path):
    """A UV-less OBJ cube in the box: under lightmap: its uv_layout becomes chart (planar without), the bake
    accepts it, and the direct light map renders like the cpu renderer's own shadowed lights."""
    (tmp_path / "cube.obj").write_text(CUBE_OBJ)
    cube = f"  - {{shape: mesh, file: {tmp_path / 'cube.obj'}, material: ball, transform: {{translate: [-0.3, 0.2, 0]}}}}\n"
    lit = BOX.format(lightmap=f"lightmap: {{directory: {tmp_path / 'lm'}, size: 32, bounces: 0}}")
    scene = load_scene(lit.replace("lights:\n", cube + "lights:\n", 1))
    plain = load_scene(BOX.format(lightmap="").replace("lights:\n", cube + "lights:\n", 1))
    assert scene.objects[-1].params["uv_layout"] == "chart" and plain.objects[-1].params["uv_layout"] == "planar"
    materials, maps, _ = baked(scene)
    E = maps[len(scene.objects) - 1]
    assert np.isfinite(E).all() and E.max() > 0
    got, _ = render_scene(scene, materials, registry=REGISTRY)
    ref, _ = render_scene(plain, mat.resolve(plain, None, REGISTRY), registry=REGISTRY)
    assert rel_rms(got, ref) < 0.1 and abs(got.mean() / ref.mean() - 1) < 0.03
    empty = load_scene(BOX.format(lightmap=""))
    without, _ = render_scene(empty, mat.resolve(empty, None, REGISTRY), registry=REGISTRY)
    assert rel_rms(without, ref) > 0.05  # the cube is in view
