"""Light-arc capture of a mesostructure: the virtual camera's height field, the arc plan, and the graph nodes."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core.errors import ParameterError, PluginError
from sbrdf_core.geometry import look_at
from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact
from sbrdf_lib.mesostructure import Mesostructure
from sbrdf_shading.arc import light_arc_angles

SMALL = {"width": 160, "height": 120, "focal_px": 200.0, "texels": [32, 32], "dist": [0, 0, 0, 0, 0]}
OVERHEAD = look_at(np.array([0.0, 0.0, 400.0]))
BUMPS = {"height_mm": {"procedural": "bumps", "amplitude_mm": 3.0, "period_mm": 12.0, "seed": 1}, "albedo": 0.5}


def camera(registry, **params):
    cam = registry.create("device", "virtual-camera", {**SMALL, **params})
    cam.bind(registry)
    return cam


def test_01_flat_mesostructure_is_a_lambertian_plane(registry):
    """Zero height, albedo ρ: L = ρ/π · I cos θ_i / r² wherever the sample is seen."""
    cam = camera(registry, effects=["falloff"], mesostructure={"height_mm": 0.0, "albedo": [0.2, 0.4, 0.6]})
    light = np.array([100.0, 50.0, 300.0])
    img = cam.photograph(light, *OVERHEAD, 1.0)
    rays = cam.rays()[60, 80]
    X = np.array([0.0, 0.0, 400.0]) + 400.0 * np.array([rays[0], -rays[1], -1.0])  # look_at: image y along -y
    d = light - X
    E = 250000.0 * d[2] / np.linalg.norm(d) ** 3
    np.testing.assert_allclose(img[60, 80], np.array([0.2, 0.4, 0.6]) / np.pi * E, rtol=1e-5)
    assert cam.effects_ran == {"falloff"}
    assert cam.simulation_info()["settings"]["mesostructure"]["facet"] == "lambert"


def test_02_effects_run_only_when_asked(registry):
    light = np.array([300.0, 0.0, 100.0])
    imgs = {}
    for eff in ([], ["shadowing"], ["masking"]):
        cam = camera(registry, effects=eff, mesostructure=BUMPS)
        imgs[tuple(eff)] = cam.photograph(light, *OVERHEAD, 1.0)
        assert cam.effects_ran == set(eff)
    base, shadowed, masked = imgs[()], imgs[("shadowing",)], imgs[("masking",)]
    lit = base > 0
    assert np.all(shadowed <= base + 1e-7) and (shadowed < base - 1e-6)[lit].mean() > 0.005
    assert not np.array_equal(base, masked)
    plain = camera(registry, effects=[])
    plain.photograph(light, *OVERHEAD, 1.0)
    assert plain.mesostructure is None and plain.effects_ran == set()


def test_03_bad_mesostructure_config_names_the_key(registry):
    with pytest.raises((ParameterError, PluginError), match="give a mesostructure"):
        camera(registry, effects=["shadowing"])
    with pytest.raises((ParameterError, PluginError), match="unknown key"):
        camera(registry, mesostructure={"height": 1.0})
    with pytest.raises((ParameterError, PluginError), match="albedo"):
        camera(registry, mesostructure={"height_mm": np.zeros((4, 5)), "albedo": np.ones((3, 3))})
    with pytest.raises((ParameterError, PluginError), match="procedural"):
        camera(registry, mesostructure={"height_mm": {"procedural": "fractal"}})


def test_04_shadow_of_a_wall_has_the_analytic_length():
    """A 1 mm wall at x ∈ [0, 0.5) lit from +x at θ_i: points within tan θ_i mm of its foot (x < 0) are dark."""
    U = 400
    h = np.zeros((4, U))
    x = (np.arange(U) + 0.5) / U * 20.0 - 10.0
    h[:, (x >= 0) & (x < 0.5)] = 1.0
    m = Mesostructure(h, 0.5, (20.0, 1.0))
    for theta in (30.0, 60.0):
        t = np.radians(theta)
        px = np.linspace(-5.0, -0.2, 200)
        pts = np.stack([px, np.zeros_like(px), np.zeros_like(px)], -1)
        light = pts + 1e6 * np.array([np.sin(t), 0.0, np.cos(t)])
        dark = m.shadowed(pts, light)
        edge = -np.tan(t)                                  # shadow from x = edge to the wall
        clear = np.abs(px - edge) > 0.1                    # away from the (texel-sized) penumbra of the march
        np.testing.assert_array_equal(dark[clear], (px > edge)[clear])


def test_05_masking_finds_the_first_hit_on_a_tilted_plane():
    """z = 0.5 + 0.1 x: the marched hit lies on the plane, nearer than the z = 0 intersection."""
    U = 200
    x = (np.arange(U) + 0.5) / U * 40.0 - 20.0
    h = np.tile(1.0 + 0.1 * x, (8, 1))
    m = Mesostructure(h, 0.5, (40.0, 4.0))
    rng = np.random.default_rng(0)
    origin = np.tile([0.0, 0.0, 100.0], (50, 1))
    d = np.stack([rng.uniform(-0.1, 0.1, 50), rng.uniform(-0.01, 0.01, 50), -np.ones(50)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    pts, hit = m.first_hit(origin, d)
    assert hit.all()
    np.testing.assert_allclose(pts[:, 2], 1.0 + 0.1 * pts[:, 0], atol=1e-3)
    s = (100.0 - pts[:, 2]) / -d[:, 2]
    np.testing.assert_allclose(pts, origin + s[:, None] * d, atol=1e-9)


def test_06_light_arc_plan_puts_the_light_at_the_wanted_elevations():
    from sbrdf_lib.rig_geometry import RigGeometry, forward

    theta = [15.0, 25.0, 35.0, 45.0, 55.0, 65.0, 75.0, 85.0]
    g = RigGeometry()
    angles = light_arc_angles(theta, g)
    poses = forward(g, *angles.T)
    wi, wo = poses.directions()
    np.testing.assert_allclose(np.degrees(np.arccos(wi[:, 2])), theta, atol=1e-9)
    np.testing.assert_allclose(wo, np.tile([0.0, 0.0, 1.0], (len(theta), 1)), atol=1e-12)   # orthogonal view
    np.testing.assert_allclose(wi[:, 1], 0.0, atol=1e-12)                                     # one arc
    with pytest.raises(ValueError, match="limits"):
        light_arc_angles([5.0], g)


def small_graph(tmp_path, capture: str) -> str:
    return textwrap.dedent(f"""\
        name: shading
        store: {tmp_path / 'store'}
        nodes:
          capture: {capture}
          register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
          shading: {{kind: ShadingMap, in: {{stack: register}}, params: {{slices: 8, tile: 16}}}}
          compress: {{kind: CompressShadingMap, in: {{shading_map: shading}}}}
        """)


def test_07_graph_linearizes_and_compresses_a_simulated_arc(tmp_path):
    cap = ("{kind: Capture, plugin: mesostructure-arc, params: {texels: [40, 24], size_mm: [10.0, 6.0], shadowing: true, "
           "mesostructure: {height_mm: {procedural: bumps, amplitude_mm: 0.3, period_mm: 2.0}, "
           "albedo: {procedural: noise, low: 0.4, high: 0.8}}}}")
    run_graph(small_graph(tmp_path, cap), progress=False)
    sm = open_artifact(f"{tmp_path}/store/shading", kind="ShadingMap")
    slices = sm.read("slices")
    assert slices.shape == (8, 24, 40, 3) and np.all(slices[0] == 0)
    np.testing.assert_allclose(slices.mean(axis=(1, 2, 3)), sm.read("slice_average"), rtol=1e-5)
    np.testing.assert_allclose(np.diff(sm.read("slice_average")), sm.attrs["a_max"] / 7, rtol=1e-9)
    np.testing.assert_allclose(sm.read("theta_i_deg"), [15, 25, 35, 45, 55, 65, 75, 85], atol=1e-9)
    assert sm.attrs["filled_samples"] == 0
    pm = open_artifact(f"{tmp_path}/store/compress", kind="PowerShadingMap")
    k_s = pm.read("k_s")
    np.testing.assert_allclose(k_s, slices[-1], rtol=1e-6)
    assert 0 < pm.attrs["rms"] < 0.1 * sm.attrs["a_max"]
    np.testing.assert_allclose(pm.attrs["rms"], np.sqrt(np.mean(pm.read("rms").astype(float) ** 2)), rtol=1e-6)
    # renderers read the artifacts through ShadingData: full and compressed agree at the slices
    from sbrdf_core.registry import default_registry
    from sbrdf_shading.shade import ShadingData, shade

    full, comp = ShadingData.from_artifacts(sm), ShadingData.from_artifacts(compressed=pm)
    assert comp.compressed and comp.a_max == full.a_max and len(comp.theta_i_deg) == 8
    lambert = default_registry().create("brdf-model", "lambert", {})
    uv = np.array([[0.3, 0.6]])
    for variant in ("r", "angle"):
        a = shade(full, lambert, {"rho_d": 0.2}, uv, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], variant=variant)
        b = shade(comp, lambert, {"rho_d": 0.2}, uv, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], variant=variant)
        assert np.isfinite(a).all() and np.abs(a - b).max() < 0.1 * a.max()


def test_08_flat_sample_through_the_nodes_gives_a_linear_map(tmp_path):
    """Flat, uniform albedo: every slice is uniform (S(r) = r) and the power fit is exact with K = 1."""
    cap = ("{kind: Capture, plugin: mesostructure-arc, params: {texels: [8, 8], size_mm: [1.0, 1.0], "
           "light_distance_mm: 1000000.0, mesostructure: {height_mm: 0.0, albedo: 0.6}}}")
    run_graph(small_graph(tmp_path, cap), progress=False)
    slices = open_artifact(f"{tmp_path}/store/shading").read("slices")
    r = open_artifact(f"{tmp_path}/store/shading").read("slice_average")
    np.testing.assert_allclose(slices, np.broadcast_to(r[:, None, None, None], slices.shape), rtol=1e-5, atol=1e-9)
    pm = open_artifact(f"{tmp_path}/store/compress")
    np.testing.assert_allclose(pm.read("exponent"), 1.0, atol=1e-6)
    assert pm.attrs["rms"] < 1e-6


def test_09_light_arc_through_the_rig_and_aruco(tmp_path):
    """The light-arc source: simulated motors + virtual camera + height field, registered by ArUco markers."""
    graph = textwrap.dedent(f"""\
        name: arc
        store: {tmp_path / 'store'}
        nodes:
          capture:
            kind: Capture
            plugin: light-arc
            params:
              path: {tmp_path / 'scan'}
              theta_i_deg: [20, 40, 60, 80]
              motors:
                sample_pan:       {{device: ptu, params: {{port: sim}}, axes: {{pan: pan_deg}}}}
                sample_tilt_roll: {{device: ptu, params: {{port: sim}}, axes: {{tilt: tilt_deg, roll: pan_deg}}}}
                light_arm:        {{device: indexer, params: {{port: sim}}, axes: {{light: angle_deg}}}}
              durable: false
              camera:
                device: virtual-camera
                params: {{width: 320, height: 240, focal_px: 1700.0, dist: [0, 0, 0, 0, 0], texels: [64, 64],
                         intensity: 2000000.0, effects: [falloff, shadowing, masking],
                         mesostructure: {{height_mm: {{procedural: bumps, amplitude_mm: 1.0, period_mm: 8.0}}, albedo: 0.6}}}}
          register: {{kind: Register, plugin: aruco, in: {{capture: capture}}, params: {{texels: [32, 32], max_rms_mm: 1.0}}}}
          shading: {{kind: ShadingMap, in: {{stack: register}}, params: {{slices: 4}}}}
        """)
    run_graph(graph, progress=False)
    reg = open_artifact(f"{tmp_path}/store/register")
    assert reg.attrs["rejected"] == [] and len(reg.read("pose_ids")) == 4
    sm = open_artifact(f"{tmp_path}/store/shading")
    np.testing.assert_allclose(sm.read("theta_i_deg"), [20, 40, 60, 80], atol=0.5)
    a = sm.read("image_average")
    assert np.all(np.diff(a) < 0)                       # lower light, darker image
    assert a[0] == pytest.approx(0.6 / np.pi * np.cos(np.radians(20)), rel=0.15)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), elevation=st.floats(0.5, 89.5), amplitude=st.floats(0.0, 2.0))
def test_10_marches_stay_finite_and_on_the_surface_at_any_angle(seed, elevation, amplitude):
    rng = np.random.default_rng(seed)
    h = amplitude * rng.uniform(0, 1, (12, 16))
    m = Mesostructure(h, 0.5, (8.0, 6.0))
    t = np.radians(elevation)
    phi = rng.uniform(0, 2 * np.pi, 40)
    d = -np.stack([np.cos(t) * np.cos(phi), np.cos(t) * np.sin(phi), np.full(40, np.sin(t))], -1)
    origin = np.stack([rng.uniform(-3, 3, 40), rng.uniform(-2, 2, 40), np.full(40, 5.0)], -1)
    pts, hit = m.first_hit(origin, d)
    assert np.isfinite(pts).all() and hit.all()
    gap = pts[:, 2] - m.height_at(pts[:, 0], pts[:, 1])
    assert np.all(np.abs(gap) <= amplitude + 1e-9)   # bracketed between the planes, refined by the secant
    assert np.median(np.abs(gap)) <= 0.05 * amplitude + 1e-9
    dark = m.shadowed(pts, pts + 1e3 * np.array([np.cos(t), 0.0, np.sin(t)]))
    assert dark.dtype == bool and dark.shape == (40,)


def test_11_black_captures_fail_cleanly_and_artifacts_open_in_a_fresh_process(tmp_path):
    import subprocess
    import sys

    from sbrdf_core.errors import ArtifactError, RunError

    cap = ("{kind: Capture, plugin: mesostructure-arc, params: {texels: [8, 8], size_mm: [1.0, 1.0], "
           "mesostructure: {height_mm: 0.0, albedo: 0.0}}}")
    with pytest.raises((RunError, ValueError), match="no positive average"):
        run_graph(small_graph(tmp_path, cap), progress=False)
    with pytest.raises(ArtifactError, match="incomplete"):                 # never a half-written artifact
        open_artifact(f"{tmp_path}/store/shading")
    cap = cap.replace("albedo: 0.0", "albedo: 0.5")
    run_graph(small_graph(tmp_path, cap), progress=False)
    # Plugins' kinds are known once a registry has loaded them (sbrdf_artifact_kinds), not by importing a plugin.
    code = ("from sbrdf_core.registry import default_registry; from sbrdf_core.store import open_artifact; "
            f"default_registry(); print(open_artifact({str(tmp_path / 'store/compress')!r}).kind)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "PowerShadingMap"
