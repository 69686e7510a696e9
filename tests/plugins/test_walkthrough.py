"""Walkthroughs: camera paths (sbrdf_lib.camera_path), a moving GLScene, the frame sequence and video."""

from __future__ import annotations

import os

import numpy as np
import pytest

from sbrdf_core.io import write_exr
from sbrdf_core.registry import default_registry
from sbrdf_lib.camera_path import camera_at, frames
from sbrdf_lib.scene import SceneError, load_scene
from sbrdf_render import materials as mat

REGISTRY = default_registry()

SCENE = """
camera: {{position: [0.0, -2.5, 1.2], look_at: [0.0, 0.0, 0.3], fov_deg: 40, resolution: [40, 30]}}
antialias: 1
materials:
  floor: {{model: lafortune, params: {{rho_d: 0.05, rho_s_1: 31.8, c_xy_1: -1.0, c_z_1: 1.0, exponent_1: 200}}}}
  ball: {{model: lafortune, params: {{rho_d: [0.1, 0.05, 0.02], rho_s_1: 5.0, c_xy_1: -1.0, c_z_1: 1.0, exponent_1: 40}}}}
objects:
  - {{shape: plane, size: [4, 4], material: floor, reflector: true}}
  - {{shape: sphere, radius: 0.4, material: ball, transform: {{translate: [0.3, 0.2, 0.4]}}}}
lights:
  - {{type: directional, direction: [0.3, -0.5, 1.0], irradiance: 2.0}}
{extra}
camera_path:
  fps: 4
  interpolation: {interp}
  keyframes:
    - {{time: 0.0, position: [0.0, -2.5, 1.2], look_at: [0.0, 0.0, 0.3]}}
    - {{time: 0.5, position: [0.8, -2.2, 1.0], look_at: [0.1, 0.1, 0.3], fov_deg: 35}}
    - {{time: 1.5, position: [0.8, -2.2, 1.0], look_at: [0.1, 0.1, 0.3], fov_deg: 35}}
    - {{time: 2.0, position: [1.5, -1.5, 1.0], look_at: [0.0, 0.0, 0.3]}}
"""


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    from sbrdf_envmap.procedural import sky as make

    path = tmp_path_factory.mktemp("sky") / "sky.exr"
    write_exr(str(path), make())
    return path


def scene(extra="", interp="catmull-rom"):
    return load_scene(SCENE.format(extra=extra, interp=interp))


@pytest.mark.parametrize("interp", ["linear", "catmull-rom"])
def test_the_path_passes_through_its_keyframes_and_holds_still(interp):
    s = scene(interp=interp)
    for key in s.camera_path.keyframes:
        cam = camera_at(s, key["time"])
        np.testing.assert_allclose(cam.position, key["position"], atol=1e-12)
        np.testing.assert_allclose(cam.look_at, key["look_at"], atol=1e-12)
    fr = frames(s)
    assert len(fr) == 9 and [f.time for f in fr] == pytest.approx(np.arange(9) / 4)
    assert [f.still for f in fr] == [False, False, False, True, True, True, True, False, False]
    assert [f.refine for f in fr][3:7] == [1, 2, 3, 4]
    assert fr[2].camera.fov_deg == 35 and fr[8].camera.fov_deg == 40
    if interp == "linear":
        np.testing.assert_allclose(fr[1].camera.position, [0.4, -2.35, 1.1])


@pytest.mark.parametrize("bad, needle", [
    ("{time: 0, position: [0, 0, 1], look_at: [0, 0, 1]}", "look_at must differ"),
    ("{time: 3, position: [0, 0, 1]}", "missing required parameter 'look_at' for camera_path keyframe 3"),
])
def test_camera_path_problems_name_the_keyframe(bad, needle):
    text = SCENE.format(extra="", interp="linear").replace(
        "    - {time: 2.0, position: [1.5, -1.5, 1.0], look_at: [0.0, 0.0, 0.3]}", "    - " + bad)
    with pytest.raises(SceneError, match=needle):
        load_scene(text)
    with pytest.raises(SceneError, match="must be after the previous keyframe"):
        load_scene(SCENE.format(extra="", interp="linear").replace("time: 2.0", "time: 1.0"))


def test_a_moved_glscene_draws_what_a_new_one_draws(gl, sky):
    """set_camera moves the main camera, the mirrored cameras and the environment background of the mirror pass."""
    s = scene(extra=f"environment: {{file: {sky}, options: {{method: sampling, size: 16, diffuse_size: 8}}}}")
    materials = mat.resolve(s, None, REGISTRY)
    target = frames(s)[8].camera
    moved = gl.GLScene(s, materials, registry=REGISTRY)
    try:
        moved.set_camera(target)
        a = moved.draw().image
    finally:
        moved.release()
    import dataclasses

    fresh = gl.GLScene(dataclasses.replace(s, camera=target), materials, registry=REGISTRY)
    try:
        b = fresh.draw().image
    finally:
        fresh.release()
    assert np.abs(a).max() > 0
    np.testing.assert_allclose(a, b, atol=1e-5 * float(np.abs(b).max()))


def test_render_path_writes_frames_video_and_refines_where_still(gl, sky, tmp_path):
    """Moving frames use the deterministic sampling, still frames the progressive QMC running mean, which gets
    closer to the converged frame (cpu Monte Carlo reference of the environment) with every still frame."""
    from sbrdf_render.cpu import render_scene
    from sbrdf_render.walkthrough import render_path

    env = f"environment: {{file: {sky}, options: {{method: sampling, size: 16, diffuse_size: 8}}}}"
    s = scene(extra=env)
    materials = mat.resolve(s, None, REGISTRY)
    stats = render_path(s, materials, str(tmp_path), registry=REGISTRY, formats=("png", "exr"), progressive_samples=4)
    assert stats["frames"] == 9 and len(stats["wall_ms"]) == 9 and all(t > 0 for t in stats["wall_ms"])
    assert stats["sampling"] == ["deterministic"] * 3 + ["progressive"] * 4 + ["deterministic"] * 2
    assert os.path.getsize(tmp_path / "walkthrough.mp4") > 0
    assert (tmp_path / "frame_0008.png").is_file() and (tmp_path / "frame_0008.exr").is_file()
    import dataclasses

    from sbrdf_core.io import read_exr

    still_cam = frames(s)[4].camera
    ref_scene = load_scene(SCENE.format(extra=env.replace("method: sampling", "method: mc, mc_samples: 256"),
                                        interp="catmull-rom"))
    ref_scene = dataclasses.replace(ref_scene, camera=dataclasses.replace(still_cam, resolution=(40, 30)))
    ref, _ = render_scene(ref_scene, mat.resolve(ref_scene, None, REGISTRY), registry=REGISTRY)
    err = [float(np.sqrt(((read_exr(str(tmp_path / f"frame_{k:04d}.exr")) - ref) ** 2).mean() / (ref ** 2).mean()))
           for k in (3, 6)]
    assert err[1] < 0.8 * err[0], err


def test_the_bake_and_walkthrough_nodes_run_as_a_graph(gl, tmp_path):
    """LightmapBake writes the scene's maps; Walkthrough (after it) writes frames, the MP4 and per-frame times;
    a second run is cached, an edited scene recomputes both."""
    from sbrdf_core.runner import run_graph
    from sbrdf_core.store import open_artifact

    scene = tmp_path / "room.yaml"
    text = SCENE.format(extra="lightmap: {directory: maps, size: 8, bounces: 1, samples: 4}", interp="linear")
    scene.write_text(text.replace("resolution: [40, 30]", "resolution: [24, 16]").replace("fps: 4", "fps: 2"))
    graph = tmp_path / "g.yaml"
    graph.write_text("name: wt\nstore: store\nnodes:\n"
                     "  bake: {kind: LightmapBake, params: {scene: room.yaml}}\n"
                     "  walk: {kind: Walkthrough, in: {lightmaps: bake}, params: {scene: room.yaml}}\n")
    run_graph(str(graph))
    assert sorted(os.listdir(tmp_path / "maps")) == ["object_000.exr", "object_001.exr"]
    art = open_artifact(str(tmp_path / "store" / "walk"))
    assert art.attrs["frames"] == 5 and (tmp_path / "store" / "walk" / "walkthrough.mp4").is_file()
    assert (tmp_path / "store" / "walk" / "frame_0004.png").is_file()
    assert art.read("wall_ms").shape == (5,) and (art.read("wall_ms") > 0).all()
    report = run_graph(str(graph))
    assert {r.status for r in report.nodes} == {"cached"}
    scene.write_text(scene.read_text().replace("samples: 4", "samples: 5"))
    report = run_graph(str(graph))
    assert report["bake"].status == "computed" and report["walk"].status == "computed"
