"""MIP-mapped SBRDFs: the Mip node's levels, trilinear lookups in cpu and gl, and the far view."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact
from sbrdf_lib.scene import SceneError, downsample, load_scene
from sbrdf_quantizers.mip import build_levels, level_errors, max_levels
from sbrdf_render import materials as mat
from sbrdf_render.cpu import render_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from render import MIP_SCENE as FAR  # noqa: E402  the distant view the benchmark measures
from render import mip_material  # noqa: E402


def random_material(size: int, seed: int = 0):
    """1-lobe Lafortune, parameters jumping from texel to texel, C_z = 1 (the gauge fits give): the benchmark's."""
    model, params = mip_material(size, seed)
    return model, params, np.concatenate([params[p.name] for p in model.parameters], -1)


def test_level_shapes_follow_opengl():
    model, params, _ = random_material(8)
    levels = build_levels(model, params, "average")
    assert [lv["rho_d"].shape for lv in levels] == [(4, 4, 3), (2, 2, 3), (1, 1, 3)]
    assert max_levels(8, 4) == 2 and max_levels(5, 9) == 2 and max_levels(1, 7) == 0
    np.testing.assert_allclose(levels[0]["rho_d"][0, 0], params["rho_d"][:2, :2].reshape(4, 3).mean(0), rtol=1e-6)
    assert len(build_levels(model, params, "average", levels=1)) == 1


def test_refit_levels_are_closer_to_the_brdf_average_than_averaged_parameters():
    model, params, _ = random_material(8, seed=1)
    refit = build_levels(model, params, "refit", levels=2, iterations=30)
    average = build_levels(model, params, "average", levels=2)
    e_refit, e_avg = level_errors(model, params, refit), level_errors(model, params, average)
    assert e_refit[0] < 0.2 * e_avg[0], (e_refit, e_avg)
    assert all(np.isfinite(v).all() for lv in refit for v in lv.values())


def test_trilinear_lookup_blends_levels():
    maps = np.zeros((4, 4, 1), np.float32)
    levels = [maps, np.ones((2, 2, 1), np.float32), np.full((1, 1, 1), 3.0, np.float32)]
    uv = np.full((5, 2), 0.3)
    got = mat.sample_trilinear(levels, uv, np.array([-1.0, 0.0, 0.5, 1.5, 7.0]))[:, 0]
    np.testing.assert_allclose(got, [0.0, 0.0, 0.5, 2.0, 3.0])
    m = mat.SceneMaterial("s", None, maps, None, "trilinear", levels=levels[1:])
    assert m.trilinear and not mat.SceneMaterial("s", None, maps, None, "trilinear").trilinear


def test_level_of_detail_is_log2_of_the_texel_footprint():
    H, W = 6, 8
    y, x = np.mgrid[0:H, 0:W].astype(float)
    uv = np.stack([x * 0.25, y * 0.125], -1)  # 16×8 texture: 4 texels per pixel in x, 1 in y
    valid = np.ones((H, W), bool)
    lam = mat.lod(uv, valid, (16, 8))
    np.testing.assert_allclose(lam, 2.0)
    valid[:, 5:] = False  # a pixel whose quad partner is elsewhere takes the neighbour on the other side
    np.testing.assert_allclose(mat.lod(uv, valid, (16, 8))[:, :5], 2.0)


def test_scene_accepts_trilinear_and_rejects_unknown_filters():
    text = ("materials: {s: {model: lambert, filter: %s}}\nobjects: [{shape: plane, material: s}]\n"
            "lights: [{type: directional, direction: [0, 0, 1], irradiance: 1}]\n")
    assert load_scene(text % "trilinear").materials["s"].filter == "trilinear"
    with pytest.raises(SceneError, match="filter"):
        load_scene(text % "anisotropic")




@pytest.fixture(scope="module")
def far():
    model, params, maps = random_material(32)
    refit = mat.pack_levels(model, build_levels(model, params, "refit", iterations=30))
    average = mat.pack_levels(model, build_levels(model, params, "average"))
    return model, maps, refit, average


def test_trilinear_cpu_and_gl_agree(far):
    gl = pytest.importorskip("sbrdf_render.gl")
    try:
        gl.context()
    except Exception as e:  # pragma: no cover - machines without EGL
        pytest.skip(f"no EGL: {e}")
    model, maps, refit, _ = far
    scene = load_scene(FAR + "antialias: 1\n")
    materials = {"s": mat.SceneMaterial("s", model, maps, None, "trilinear", levels=refit)}
    cpu, _ = render_scene(scene, materials)
    s = gl.GLScene(scene, materials)
    try:
        img = s.draw().image.astype(np.float64)
        assert "u_params_0" in s.programs["s"]
    finally:
        s.release()
    hit = cpu.max(-1) > 0
    rel = np.abs(img - cpu).max(-1)[hit] / np.abs(cpu[hit]).max()
    # llvmpipe takes one level of detail per 2×2 quad with an approximate log2; cpu per pixel
    assert np.sqrt(np.mean(rel**2)) < 1e-2 and rel.max() < 0.1, (np.sqrt(np.mean(rel**2)), rel.max())
    bilinear, _ = render_scene(scene, {"s": mat.SceneMaterial("s", model, maps, None, "bilinear")})
    assert np.abs(bilinear - cpu)[hit].mean() > 10 * np.abs(img - cpu)[hit].mean()  # the levels are used
    aa = load_scene(FAR.replace("[64, 48]", "[32, 24]"))  # antialias 4: both choose levels on the 2×2 grid
    cpu, _ = render_scene(aa, materials)
    s = gl.GLScene(aa, materials)
    try:
        img = s.draw().image.astype(np.float64)
    finally:
        s.release()
    hit = cpu.max(-1) > 0
    rel = np.abs(img - cpu).max(-1)[hit] / np.abs(cpu[hit]).max()
    assert np.sqrt(np.mean(rel**2)) < 1e-2, np.sqrt(np.mean(rel**2))


def test_far_view_with_refit_levels_is_closer_to_the_supersampled_reference(far):
    model, maps, refit, average = far
    ref, _ = render_scene(load_scene(FAR.replace("[64, 48]", "[128, 96]") + "antialias: 64\n"),
                          {"s": mat.SceneMaterial("s", model, maps, None, "nearest")})
    ref = downsample(ref, 2)
    hit = ref.max(-1) > 0
    scene = load_scene(FAR + "antialias: 1\n")

    def err(m):
        img, _ = render_scene(scene, {"s": m})
        return float(np.abs(img - ref)[hit].mean() / np.abs(ref[hit]).mean()), img

    e0, level0 = err(mat.SceneMaterial("s", model, maps, None, "bilinear"))
    e_refit, img = err(mat.SceneMaterial("s", model, maps, None, "trilinear", levels=refit))
    e_avg, _ = err(mat.SceneMaterial("s", model, maps, None, "trilinear", levels=average))
    assert np.abs(img - level0)[hit].mean() > 0.05 * np.abs(ref[hit]).mean()
    assert e_refit < 0.7 * e0 and e_refit < 0.5 * e_avg, (e_refit, e0, e_avg)


def test_mip_node_stores_levels_beside_level_0_and_renders(tmp_path):
    scene = tmp_path / "far.yaml"
    scene.write_text(FAR.replace("{model: lafortune}", "{artifact: input, filter: trilinear}")
                     .replace("material: s", "material: s") + "antialias: 1\n")
    text = textwrap.dedent(f"""\
        name: mip
        store: {tmp_path / 's'}
        nodes:
          a: {{kind: SampleModel, params: {{model: lambert, texels: [8, 4], poses: 20}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: a}}, params: {{model: lambert}}}}
          mip: {{kind: Mip, in: {{params: fit}}, params: {{method: refit, iterations: 10}}}}
          avg: {{kind: Mip, in: {{params: fit}}, params: {{method: average}}}}
          meas: {{kind: Mip, in: {{params: fit, samples: a}}, params: {{method: samples, levels: 1, iterations: 10}}}}
          q: {{kind: Quantize, plugin: fixed16, in: {{params: mip}}}}
          r: {{kind: Render, plugin: cpu, in: {{material: mip}}, params: {{scene: {scene}}}}}
        """)
    run_graph(text, progress=False)
    art = open_artifact(f"{tmp_path / 's'}/mip")
    fit = open_artifact(f"{tmp_path / 's'}/fit")
    assert art.kind == "ParamMaps" and art.attrs["mip"]["levels"] == 2
    assert art.attrs["mip"]["shapes"] == [[4, 8], [2, 4], [1, 2]]
    assert art.read("mip/1/rho_d").shape == (2, 4, 3) and art.read("mip/2/rho_d").shape == (1, 2, 3)
    np.testing.assert_array_equal(art.read("params/rho_d"), fit.read("params/rho_d"))
    avg = open_artifact(f"{tmp_path / 's'}/avg")
    np.testing.assert_allclose(avg.read("mip/1/rho_d")[0, 0], fit.read("params/rho_d")[:2, :2].reshape(4, 3).mean(0),
                               rtol=1e-5)
    meas = open_artifact(f"{tmp_path / 's'}/meas")
    assert meas.attrs["mip"]["levels"] == 1 and meas.read("mip/1/rho_d").shape == (2, 4, 3)
    assert np.isfinite(meas.read("mip/1/rho_d")).all() and meas.attrs["mip"]["error"][0] < 1e-2
    assert open_artifact(f"{tmp_path / 's'}/q").attrs["added_rms"] < 1e-2
    assert np.isfinite(open_artifact(f"{tmp_path / 's'}/r").read("image")).all()


def test_trilinear_without_levels_is_bilinear(far):
    model, maps, _, _ = far
    scene = load_scene(FAR.replace("[64, 48]", "[32, 24]"))  # default antialiasing
    a, _ = render_scene(scene, {"s": mat.SceneMaterial("s", model, maps, None, "trilinear")})
    b, _ = render_scene(scene, {"s": mat.SceneMaterial("s", model, maps, None, "bilinear")})
    np.testing.assert_array_equal(a, b)
