"""The example third-party package (docs/examples/sbrdf-example-plugin) works like a built-in.

Its three contributions, each tested the way docs/plugin-guide.md says to test one: the ``minnaert`` BRDF model
(here the entry point, Jacobian and a full graph; the model contract tests in test_models.py cover it too), the
``turntable`` device (the real driver against its pty simulator with injected faults, and in a ``gonio`` capture),
and the ``ambient`` scene effect (cpu and gl against a closed form and each other).
"""

from __future__ import annotations

import functools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core.graph import load_graph
from sbrdf_core.registry import Registry
from sbrdf_core.runner import Runner, run_graph
from sbrdf_core.store import open_artifact

from ..conftest import graph_yaml, synthetic_truth

pytest.importorskip("sbrdf_example", reason="install docs/examples/sbrdf-example-plugin (CI does)")


def test_minnaert_is_discovered_through_its_entry_point(registry):
    spec = registry.get("brdf-model", "minnaert")
    assert spec.distribution == "sbrdf-example-plugin" and spec.plugin == "example"


def test_the_manifest_imports_no_implementation():
    """Loading the registry (every sbrdf command) must not import the model, the driver, the effect or pyserial.

    (Asking for a spec's parameters, ``Registry.get``, imports the implementation that declares them.)
    """
    modules = ["sbrdf_example.minnaert", "sbrdf_example.turntable", "sbrdf_example.turntable_sim",
               "sbrdf_example.ambient", "serial"]
    code = ("import sys; from sbrdf_core.registry import Registry; r = Registry(); "
            "assert 'turntable' in r.names('device'); "
            f"print([m for m in {modules!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


def test_minnaert_jacobian_matches_finite_differences(registry):
    from sbrdf_core.brdf import BRDFModel
    from sbrdf_core.geometry import fibonacci_hemisphere

    m = registry.create("brdf-model", "minnaert")
    d = fibonacci_hemisphere(8)
    wi, wo = np.broadcast_to(d, (4, 8, 3)), np.broadcast_to(d[::-1], (4, 8, 3))
    p = {"rho_d": np.full((4, 3), 0.2), "k": np.linspace(0.6, 1.4, 4)[:, None]}
    np.testing.assert_allclose(m.jacobian(p, wi, wo), BRDFModel.jacobian(m, p, wi, wo), rtol=1e-5, atol=1e-8)


def test_graph_with_the_example_model_runs_and_recovers_it(write_graph, registry, tmp_path):
    g = load_graph(write_graph(graph_yaml(tmp_path / "s", {"model": "minnaert", "noise": 0.0, "poses": 24},
                                          {"model": "minnaert"})), registry)
    Runner(registry).run(g)
    fit = open_artifact(str(tmp_path / "s" / "fit"))
    assert fit.attrs["model"] == "minnaert"
    truth = synthetic_truth(registry, texels=[24, 20], poses=24, model="minnaert")
    np.testing.assert_allclose(fit.read("params/k"), truth["k"], atol=1e-3)
    np.testing.assert_allclose(fit.read("params/rho_d"), truth["rho_d"], rtol=1e-3)
    assert np.isfinite(open_artifact(str(tmp_path / "s" / "render")).read("image")).all()


# -- the device: the turntable driver against its pty simulator ---------------------------------------------------
#
# Nothing is mocked: the simulator serves the protocol on a pseudo-terminal and the driver opens it with pyserial,
# as it would open /dev/ttyUSB0.  Faults (dropped, garbled, late replies, missed moves) are injected as data.

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "sbrdf-example-plugin"


@pytest.fixture
def turntable_sim(start_simulator):
    """Start turntable simulators for a test: ``sim = turntable_sim(faults=[...])``; all stop at teardown."""
    from sbrdf_example.turntable_sim import SimulatedTurntable

    return functools.partial(start_simulator, SimulatedTurntable)


def turntable(registry, sim, **params):
    return registry.create("device", "turntable", {"port": sim.port, **params})


def test_turntable_is_a_device_of_the_example_distribution(registry):
    spec = registry.get("device", "turntable")
    assert spec.distribution == "sbrdf-example-plugin" and spec.plugin == "example"
    assert [p.name for p in spec.params][:3] == ["port", "baudrate", "timeout_s"]


def test_turntable_moves_verifies_and_stops(registry, turntable_sim):
    sim = turntable_sim()
    with turntable(registry, sim) as stage:
        assert stage.move_to(angle_deg=-37.5) == {"angle_deg": -37.5}
        assert stage.position() == {"angle_deg": -37.5} and sim.position_deg() == -37.5
        stage.move_to(**stage.position())  # a no-op round trip
        stage.stop()
    assert not stage.is_open
    assert sim.received[:2] == ["Q", "G-37.500"] and sim.received[-1] == "S"  # connect probes; close halts


@settings(max_examples=20, deadline=None)
@given(target=st.floats(-200.0, 200.0, allow_nan=False))
def test_turntable_reaches_every_angle_inside_the_limits_and_sends_nothing_outside(target):
    """Inside [-180, 180]: read back within 0.5 mdeg (the stage's resolution); outside: refused, nothing sent."""
    from sbrdf_example.turntable_sim import SimulatedTurntable
    from sbrdf_lib.serial import SoftLimitError

    with SimulatedTurntable() as sim, Registry().create("device", "turntable", {"port": sim.port}) as stage:
        before = list(sim.received)
        if -180.0 <= target <= 180.0:
            assert abs(stage.move_to(angle_deg=target)["angle_deg"] - target) <= 5e-4
            assert abs(sim.position_deg() - target) <= 5e-4
        else:
            with pytest.raises(SoftLimitError, match=r"outside the soft limits \[-180, 180\] deg; nothing was sent"):
                stage.move_to(angle_deg=target)
            assert sim.received == before


def test_transient_faults_are_retried_and_recorded(registry, turntable_sim):
    from sbrdf_lib.serial import Fault

    # The first move's reply is dropped (the stage moved; the driver re-sends the absolute move), the first
    # Q after connecting is garbled and a later one late (both re-sent), and the re-sent move misses by 0.5 deg
    # (the read-back catches it and the move is commanded once more).
    sim = turntable_sim(faults=[Fault("drop", match="G.*"), Fault("garble", match="Q", skip=1),
                                Fault("stall", match="Q", skip=3, stall_s=0.3), Fault("miss", skip=1, miss_deg=0.5)])
    with turntable(registry, sim, timeout_s=0.1, retries=2) as stage:
        assert stage.move_to(angle_deg=90.0) == {"angle_deg": 90.0}
        assert sim.position_deg() == 90.0
        failures = " ".join(err for _, err in stage.link.recovered)
        assert "no complete reply" in failures and "not ASCII" in failures
        assert stage.position_misses == [("angle_deg", 90.0, 90.5)]


@pytest.mark.parametrize("kind,error,message", [("drop", "ReplyTimeout", "no complete reply within 0.1 s"),
                                                ("garble", "GarbledReply", "reply is not ASCII")])
def test_persistent_reply_fault_is_a_clear_error_and_closes_the_port(registry, turntable_sim, kind, error, message):
    from sbrdf_lib.serial import Fault, errors

    sim = turntable_sim()
    stage = turntable(registry, sim, timeout_s=0.1, retries=1)
    sim.add_fault(Fault(kind, match="Q", times=None))
    with pytest.raises(getattr(errors, error)) as info:
        stage.move_to(angle_deg=10.0)
    text = str(info.value)
    assert text.startswith(f"turntable on {sim.port}: {message}; gave up after 2 attempts (command 'Q', received ")
    assert info.value.command == "Q" and info.value.port == sim.port
    assert not stage.is_open and sim.received[-1] == "S"  # halted (best effort) and released
    with pytest.raises(errors.DeviceClosed, match="driver is closed"):
        stage.position()


def test_a_refusal_is_not_retried(registry, turntable_sim):
    from sbrdf_lib.serial import DeviceRefused

    sim = turntable_sim(range_deg=90.0)  # the hardware range is narrower than the driver's soft limits
    stage = turntable(registry, sim)
    with pytest.raises(DeviceRefused, match=r"stage refused: RANGE \+120.000 OUTSIDE \+-90 .*command 'G\+120.000'"):
        stage.move_to(angle_deg=120.0)
    assert sim.received.count("G+120.000") == 1 and not stage.is_open


def test_something_else_on_the_port_fails_at_connect(registry, turntable_sim):
    from sbrdf_lib.serial import GarbledReply

    sim = turntable_sim()
    sim.handle = lambda command: "HELLO"  # a different device answers
    with pytest.raises(GarbledReply, match=r"expected 'Q <angle> MOVING\|IDLE'.*received 'HELLO'"):
        turntable(registry, sim, timeout_s=0.2, retries=0)


def test_example_gonio_graph_captures_with_the_turntable_on_the_light_arm(tmp_path, registry):
    """The example graph (``port: sim`` on a third-party device) validates as shipped and runs a tiny capture."""
    import yaml

    from sbrdf_lib.capture_folder import load_manifest

    source = EXAMPLE / "graphs" / "turntable-gonio.yaml"
    load_graph(str(source), registry)
    data = yaml.safe_load(source.read_text())
    params = data["nodes"]["capture"]["params"]
    assert params["motors"]["light_arm"]["device"] == "turntable" and params["motors"]["light_arm"]["params"]["port"] == "sim"
    params["path"] = str(tmp_path / "scan")
    params["plan"]["angles_deg"] = params["plan"]["angles_deg"][:3]
    params["camera"]["params"].update(width=48, height=36, focal_px=180.0, texels=[8, 8])
    data["store"] = str(tmp_path / "store")
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(data))
    rep = run_graph(str(tmp_path / "g.yaml"))
    assert rep["capture"].status == "computed"
    m = load_manifest(tmp_path / "scan")
    assert m.complete and m.extra["rig"]["motors"]["light_arm"]["device"] == "turntable"
    assert [p.extra["motors"]["read_deg"]["light"] for p in m.poses] == [30.0, 45.0, 60.0]
    images = open_artifact(str(tmp_path / "store" / "capture")).read("images")
    assert images.shape[0] == 3 and np.isfinite(images).all() and images.max() > 0


def test_port_sim_needs_a_simulator(tmp_path, registry, monkeypatch):
    from sbrdf_core.errors import ParameterError
    from sbrdf_example.turntable import Turntable

    monkeypatch.delattr(Turntable, "simulator")
    source = registry.create("capture", "gonio", {
        "path": str(tmp_path / "scan"), "plan": {"angles_deg": [[0, 0, 0, 30]]},
        "motors": {"arm": {"device": "turntable", "params": {"port": "sim"}, "axes": {"light": "angle_deg"}}}})
    with pytest.raises(ParameterError, match=r"motors.arm: port: sim needs a simulator, and device 'turntable' has none"):
        source.bind(registry)


# -- the scene effect: a uniform sky (ambient) on the cpu and gl renderers --------------------------------------------


def ambient_scene(model: str = "lambert", ambient: bool = True, shape: str = "plane") -> str:
    materials = {"lambert": "{model: lambert, params: {rho_d: [0.25, 0.15, 0.05]}}",
                 "minnaert": "{model: minnaert, params: {rho_d: [0.2, 0.1, 0.05], k: 0.7}}"}[model]
    obj = "{shape: plane, size: [40, 40], material: m}" if shape == "plane" else "{shape: sphere, radius: 0.8, material: m}"
    return (f"camera: {{position: [0.3, -1.2, 1.5], look_at: [0, 0, 0], fov_deg: 60, resolution: [80, 60]}}\n"
            f"materials: {{m: {materials}}}\n"
            f"objects: [{obj}]\n"
            "lights: [{type: directional, direction: [0.3, 0.2, 1.0], irradiance: [1, 1, 1]}]\n"
            + ("effects: {ambient: {radiance: [0.5, 0.4, 0.3]}}\n" if ambient else "")
            + "antialias: 1\n")  # the closed forms below are per pixel centre


def render_both(gl, registry, text: str):
    """(cpu image, gl image, the gl shader sources, hits, hit object per pixel, rays) of a scene as YAML text."""
    from sbrdf_lib.scene import load_scene
    from sbrdf_render import materials as mat
    from sbrdf_render.cpu import cast, render_scene

    scene = load_scene(text)
    materials = mat.resolve(scene, None, registry)
    cpu, _ = render_scene(scene, materials, registry=registry)
    drawer = gl.GLScene(scene, materials, registry=registry)
    try:
        gpu = drawer.draw().image.astype(np.float64)
        shader = "\n".join(drawer.sources["m"])
    finally:
        drawer.release()
    dirs, origin = scene.camera.rays()
    hits, which = cast(scene, materials, dirs.reshape(-1, 3), origin)
    return cpu, gpu, shader, hits, which.reshape(gpu.shape[:2]), dirs.reshape(-1, 3)


def test_ambient_on_a_lambertian_plane_adds_pi_a_rho_d_on_both_renderers(gl, registry):
    """For a Lambertian surface the one-sample sky is exact: L_ambient = π A ρ_d at every pixel."""
    cpu0, gpu0, shader0, *_ = render_both(gl, registry, ambient_scene(ambient=False))
    cpu, gpu, shader, _, which, _ = render_both(gl, registry, ambient_scene())
    assert (which >= 0).all()
    expect = np.pi * np.array([0.5, 0.4, 0.3]) * np.array([0.25, 0.15, 0.05])
    np.testing.assert_allclose(cpu - cpu0, np.broadcast_to(expect, cpu.shape), rtol=1e-6)
    np.testing.assert_allclose(gpu - gpu0, np.broadcast_to(expect, gpu.shape), rtol=1e-4, atol=1e-6)
    assert "u_ambient_radiance" in shader and "u_ambient_radiance" not in shader0  # only when the scene asks


@pytest.mark.parametrize("shape", ["plane", "sphere"])
def test_ambient_glsl_matches_numpy_on_minnaert(gl, registry, shape):
    """GLSL term against numpy term against the closed form π A ρ_d (cos θ_o)^(k−1) (wi = n), pixel by pixel.

    The plane has exact normals on both renderers; the sphere is tessellated for gl (interpolated normals), so
    there gl is compared with the reference as the renderer tests do, on the interior and by relative error.
    """
    cpu0, gpu0, *_ = render_both(gl, registry, ambient_scene("minnaert", ambient=False, shape=shape))
    cpu, gpu, _, hits, which, dirs = render_both(gl, registry, ambient_scene("minnaert", shape=shape))
    hit = which.ravel() >= 0
    cos_o = np.einsum("ij,ij->i", hits.normal[hit], -dirs[hit]) / np.linalg.norm(hits.normal[hit], axis=1)
    expect = np.pi * np.array([0.5, 0.4, 0.3]) * np.array([0.2, 0.1, 0.05]) * (np.clip(cos_o, 1e-3, 1) ** -0.3)[:, None]
    term_cpu, term_gpu = (cpu - cpu0).reshape(-1, 3), (gpu - gpu0).reshape(-1, 3)
    np.testing.assert_allclose(term_cpu[hit], expect, rtol=1e-6)
    assert np.all(term_cpu[~hit] == 0) and np.ptp(expect[:, 0]) > 0.02  # the term varies over the image
    if shape == "plane":
        np.testing.assert_allclose(term_gpu, term_cpu, rtol=1e-4, atol=1e-6)
    else:
        inner = np.zeros(len(hit), bool)
        inner[np.flatnonzero(hit)[cos_o > 0.3]] = True
        rel = np.abs(term_gpu[inner] - term_cpu[inner]) / term_cpu[inner]
        assert inner.sum() > 500 and np.sqrt(np.mean(rel**2)) < 5e-3 and rel.max() < 0.02


def test_scenes_without_it_do_not_construct_it(registry):
    from sbrdf_lib.scene import load_scene
    from sbrdf_render.effects import active_effects

    assert [e.name for e in active_effects(load_scene(ambient_scene()), registry)] == ["ambient"]
    assert active_effects(load_scene(ambient_scene(ambient=False)), registry) == []


def test_bad_ambient_options_name_the_scene_and_the_parameter(registry, tmp_path):
    from sbrdf_core.errors import SbrdfError
    from sbrdf_lib.scene import load_scene
    from sbrdf_render.effects import active_effects

    path = tmp_path / "sky.yaml"
    path.write_text(ambient_scene().replace("radiance: [0.5, 0.4, 0.3]", "radiance: [0.5, -1, 0.3]"))
    with pytest.raises(SbrdfError, match=rf"{path}: scene effect 'ambient': .*radiance"):
        active_effects(load_scene(str(path)), registry)


def test_an_effect_no_plugin_provides_is_an_error_not_ignored(registry, tmp_path):
    from sbrdf_core.errors import SbrdfError
    from sbrdf_lib.scene import SceneError, load_scene
    from sbrdf_render import materials as mat
    from sbrdf_render.cpu import render_scene

    path = tmp_path / "typo.yaml"
    path.write_text(ambient_scene().replace("ambient:", "ambiant:"))
    scene = load_scene(str(path))
    with pytest.raises(SbrdfError, match=rf"{path}: effects: no installed scene effect provides \['ambiant'\]"):
        render_scene(scene, mat.resolve(scene, None, registry), registry=registry)
    path.write_text(ambient_scene().replace("{ambient: {radiance: [0.5, 0.4, 0.3]}}", "[ambient]"))
    with pytest.raises(SceneError, match=r"typo.yaml:5: effects must map scene-effect names to their options"):
        load_scene(str(path))
