"""The gltf exporter (plugins/sbrdf_export/gltf.py): Khronos-valid files, a faithful read-back, an Export node in a graph."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sbrdf_core.nodes.render import Material
from sbrdf_core.registry import Registry

PLUGINS = ("sbrdf_export",)
#: The round trips' scene: the sample on a plane and a sphere under two point lights (``w`` × ``h`` pixels).
ROUND_TRIP_SCENE = textwrap.dedent("""\
    camera: {{position: [0, -1.5, 1.5], look_at: [0, 0, 0.2], fov_deg: 45, resolution: [{w}, {h}]}}
    materials:
      sample: {{artifact: input, filter: nearest}}
    objects:
      - {{shape: plane, size: [1.5, 1.5]}}
      - {{shape: sphere, radius: 0.3, transform: {{translate: [0, 0, 0.3]}}}}
    lights: [{{type: point, position: [1, -1, 2], intensity: 5}}, {{type: point, position: [-1, 1, 1.5], intensity: 2}}]
    """)
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def reg():
    return Registry(extra=PLUGINS)


def material(reg, V=6, U=8):
    """Dielectric and metal cook-torrance texels plus one black texel, a 40 x 30 mm sample."""
    da = pytest.importorskip("dask.array")
    ct = reg.create("brdf-model", "cook-torrance", {"distribution": "ggx"})
    rng = np.random.default_rng(7)
    T = V * U
    metal = np.arange(T) % 3 == 0
    p = {"rho_d": np.where(metal[:, None], 0.0, rng.uniform(0.02, 0.25, (T, 3))),
         "f0": np.where(metal[:, None], rng.uniform(0.5, 0.95, (T, 3)), np.where(np.arange(T)[:, None] % 3 == 1, 0.04, 0.08)),
         "alpha": rng.uniform(0.1, 0.6, (T, 1))}
    p["rho_d"][2], p["f0"][2] = 0.0, 0.0
    return Material(ct, {k: da.from_array(v.reshape(V, U, -1), chunks=(4, 4, -1)) for k, v in p.items()}, (U, V),
                    (40.0, 30.0), "test"), p


@pytest.fixture(scope="module")
def exported(reg, tmp_path_factory):
    mat, p = material(reg)
    ex = reg.create("exporter", "gltf", {"tile": 4})
    ex.bind(reg)
    lazy = ex.convert(mat)
    assert all(hasattr(v, "dask") for v in lazy.values())  # lazy until stored
    import dask

    maps = dict(zip(lazy, (np.asarray(v) for v in dask.compute(*lazy.values()))))
    out = {}
    for fmt in ("gltf", "glb"):
        d = tmp_path_factory.mktemp(fmt)
        ex.format = fmt
        out[fmt] = (d, ex.write(str(d), maps, mat))
    return mat, p, maps, out


def validator() -> tuple[str, str] | None:
    """``(node, path of the gltf-validator package)`` or None."""
    node = shutil.which("node")
    if node is None:
        return None
    for cand in (os.environ.get("SBRDF_GLTF_VALIDATOR"), ROOT / ".cache" / "npm" / "node_modules" / "gltf-validator",
                 ROOT / "node_modules" / "gltf-validator"):
        if cand and Path(cand, "package.json").exists():
            return node, str(cand)
    r = subprocess.run([node, "-e", "console.log(require.resolve('gltf-validator'))"], capture_output=True, text=True)
    return (node, os.path.dirname(r.stdout.strip())) if r.returncode == 0 else None


VALIDATE_JS = """
const v = require(process.argv[1]); const fs = require('fs'); const path = require('path');
const file = process.argv[2];
v.validateBytes(new Uint8Array(fs.readFileSync(file)), {uri: path.basename(file), maxIssues: 200,
  externalResourceFunction: (uri) => new Promise((res, rej) => fs.readFile(path.join(path.dirname(file),
    decodeURIComponent(uri)), (e, d) => e ? rej(e.toString()) : res(new Uint8Array(d))))})
 .then(r => console.log(JSON.stringify(r))).catch(e => { console.error(String(e)); process.exit(2); });
"""


@pytest.mark.parametrize("fmt", ["gltf", "glb"])
def test_khronos_validator_finds_no_errors_or_warnings(exported, fmt):
    found = validator()
    if found is None:
        pytest.skip("the Khronos glTF validator is not installed: npm install --prefix .cache/npm gltf-validator "
                    "(needs node)")
    node, pkg = found
    d, attrs = exported[3][fmt]
    main = next(f for f in attrs["files"] if f.endswith(("gltf", "glb")))
    r = subprocess.run([node, "-e", VALIDATE_JS, pkg, str(d / main)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    issues = report["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    assert report["info"]["extensionsUsed"] == ["KHR_materials_specular"]
    assert report["info"]["materialCount"] == 1 and report["info"]["totalTriangleCount"] == 2


def test_files_quad_and_extension(exported):
    mat, p, maps, out = exported
    d, attrs = out["gltf"]
    assert attrs["files"] == ["material.gltf", "material.bin", "material_base_color.png",
                              "material_metallic_roughness.png", "material_specular.png",
                              "material_conversion_error.exr", "material_flagged.png"]
    assert attrs["flagged"] == 0 and attrs["flag_error"] == 0.25
    assert attrs["extensions"] == ["KHR_materials_specular"] and attrs["specular_color_factor"] == pytest.approx(2.0, abs=0.01)
    doc = json.loads((d / "material.gltf").read_text())
    assert doc["asset"]["version"] == "2.0" and doc["extensionsUsed"] == ["KHR_materials_specular"]
    pos = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    np.testing.assert_allclose(pos["max"], [0.02, 0.0, 0.015], rtol=1e-6)  # 40 x 30 mm, facing +Y
    assert doc["materials"][0]["extras"]["sbrdf"]["model"] == "cook-torrance"
    assert out["glb"][1]["files"] == ["material.glb", "material_conversion_error.exr", "material_flagged.png"]


@pytest.mark.parametrize("fmt", ["gltf", "glb"])
def test_read_back_matches_the_conversion_within_8_bit_quantisation(exported, fmt):
    from sbrdf_export.gltf import gltf_maps_to_ggx, read_gltf

    mat, p, maps, out = exported
    d, attrs = out[fmt]
    back = read_gltf(str(d / attrs["files"][0]))
    for k in ("metallic", "roughness", "specular"):
        np.testing.assert_allclose(back[k], maps[k], atol=0.6 / 255 + 1e-6)
    np.testing.assert_allclose(back["base_color"], maps["base_color"], atol=0.01)
    ggx = gltf_maps_to_ggx(back)
    V, U = maps["error"].shape[:2]
    f0 = p["f0"].reshape(V, U, 3)
    np.testing.assert_allclose(ggx["f0"], f0, atol=0.01)
    np.testing.assert_allclose(np.sqrt(ggx["alpha"]), np.sqrt(p["alpha"].reshape(V, U, 1)), atol=0.6 / 255 + 1e-6)
    assert maps["error"].reshape(-1)[2] < 1e-6  # F0 = 0: only the Schlick grazing term, exactly as in glTF
    assert np.median(maps["error"]) < 0.03


def test_reading_back_a_malformed_file_names_what_is_wrong(tmp_path):
    """A GLB without its JSON chunk, or a texture that is not an image, used to fail deep inside the reader
    (subscripting None, or None.ndim); they are refused with what is wrong."""
    import json
    import struct

    from sbrdf_export.gltf import read_gltf

    binary = struct.pack("<II", 4, 0x004E4942) + b"\0\0\0\0"  # a BIN chunk only
    glb = tmp_path / "no-json.glb"
    glb.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(binary)) + binary)
    with pytest.raises(ValueError, match="without its JSON chunk"):
        read_gltf(str(glb))
    (tmp_path / "base.png").write_bytes(b"not a PNG")
    doc = {"asset": {"version": "2.0"}, "images": [{"uri": "base.png"}], "textures": [{"source": 0}],
           "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]}
    (tmp_path / "bad-texture.gltf").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"texture 0 \(base.png\) is not an image"):
        read_gltf(str(tmp_path / "bad-texture.gltf"))


def test_round_trip_renders_like_the_original(reg, exported):
    """The material read back from glTF renders through `cpu` like the fitted original (stated: < 5 % mean)."""
    pytest.importorskip("dask.array")
    import dask.array as da

    from sbrdf_export.gltf import gltf_maps_to_ggx, read_gltf

    mat, p, maps, out = exported
    d, attrs = out["gltf"]
    back = gltf_maps_to_ggx(read_gltf(str(d / "material.gltf")))
    mat2 = Material(mat.model, {k: da.from_array(v) for k, v in back.items()}, mat.texels, mat.size_mm, "gltf")
    scene = d / "scene.yaml"
    scene.write_text(ROUND_TRIP_SCENE.format(w=48, h=36))
    r = reg.create("renderer", "cpu", {"scene": str(scene)})
    a, b = np.asarray(r.render(mat).image), np.asarray(r.render(mat2).image)
    rel = np.abs(a - b).sum() / np.abs(a).sum()
    assert a.max() > 0 and rel < 0.05


def test_export_node_in_a_graph(reg, tmp_path):
    from sbrdf_core.runner import run_graph
    from sbrdf_core.store import open_artifact

    g = textwrap.dedent(f"""\
        name: export
        store: {tmp_path / 's'}
        nodes:
          capture: {{kind: Capture, plugin: synthetic, params: {{texels: [6, 4], poses: 16, model: lafortune, seed: 5}}}}
          register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
          reflectance: {{kind: Reflectance, in: {{stack: register}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lafortune}}}}
          gltf: {{kind: Export, plugin: gltf, in: {{material: fit}}, params: {{format: glb}}}}
        """)
    run_graph(g, progress=False, registry=reg)
    art = open_artifact(f"{tmp_path / 's'}/gltf")
    assert art.attrs["exporter"] == "gltf"
    assert art.attrs["files"] == ["material.glb", "material_conversion_error.exr", "material_flagged.png"]
    assert 0 <= art.attrs["error_mean"] < 1 and np.isfinite(art.attrs["error_max"])
    assert art.read("maps/roughness").shape == (4, 6, 1) and art.read("error").shape == (4, 6, 1)
    flagged = art.read("maps/flagged")[..., 0] > 0.5  # stored per texel beside the error it is read from
    np.testing.assert_array_equal(flagged, art.read("error")[..., 0] > 0.25)
    assert art.attrs["flagged"] == int(flagged.sum())
    assert (tmp_path / "s" / "gltf" / "material.glb").read_bytes()[:4] == b"glTF"


# -- KHR_materials_anisotropy ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def anisotropic_export(reg, tmp_path_factory):
    """An anisotropic GGX sample (directions varying over the texels, a few isotropic texels) exported as glTF."""
    da = pytest.importorskip("dask.array")
    import dask

    model = reg.create("brdf-model", "ggx-anisotropic", {})
    V, U = 6, 8
    T = V * U
    rng = np.random.default_rng(3)
    metal = (np.arange(T) % 2 == 0)[:, None]  # brushed metal, or a dielectric (glTF has no coloured-F0 dielectric)
    p = {"rho_d": np.where(metal, 0.0, rng.uniform(0.02, 0.15, (T, 3))),
         "f0": np.where(metal, rng.uniform(0.5, 0.95, (T, 3)), 0.04),
         "alpha_t": rng.uniform(0.3, 0.6, (T, 1)), "alpha_b": rng.uniform(0.05, 0.15, (T, 1)),
         "phi": rng.uniform(-np.pi / 2, np.pi / 2, (T, 1))}
    p["alpha_b"][::7] = p["alpha_t"][::7]  # isotropic texels
    mat = Material(model, {k: da.from_array(v.reshape(V, U, -1), chunks=(3, 4, -1)) for k, v in p.items()}, (U, V),
                   (40.0, 30.0), "test")
    ex = reg.create("exporter", "gltf", {"tile": 4})
    ex.bind(reg)
    lazy = ex.convert(mat)
    maps = dict(zip(lazy, (np.asarray(v) for v in dask.compute(*lazy.values()))))
    d = tmp_path_factory.mktemp("aniso")
    return mat, p, maps, d, ex.write(str(d), maps, mat)


def test_anisotropic_material_writes_khr_materials_anisotropy_that_the_validator_accepts(anisotropic_export):
    mat, p, maps, d, attrs = anisotropic_export
    assert attrs["extensions"] == ["KHR_materials_anisotropy"]
    assert "material_anisotropy.png" in attrs["files"]
    doc = json.loads((d / "material.gltf").read_text())
    assert "TANGENT" in doc["meshes"][0]["primitives"][0]["attributes"]
    found = validator()
    if found is None:
        pytest.skip("the Khronos glTF validator is not installed (npm install --prefix .cache/npm gltf-validator)")
    r = subprocess.run([found[0], "-e", VALIDATE_JS, found[1], str(d / "material.gltf")], capture_output=True, text=True,
                       timeout=120)
    report = json.loads(r.stdout)
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, report["issues"]["messages"]
    assert report["info"]["extensionsUsed"] == ["KHR_materials_anisotropy"]


def test_anisotropy_reads_back_as_the_source_lobe(anisotropic_export):
    from sbrdf_export.gltf import gltf_maps_to_ggx, read_gltf

    mat, p, maps, d, attrs = anisotropic_export
    back = gltf_maps_to_ggx(read_gltf(str(d / "material.gltf")))
    want = mat.model.canonical({k: v for k, v in p.items()})
    V, U = maps["error"].shape[:2]
    got = mat.model.canonical({k: back[k].reshape(V * U, -1) for k in ("rho_d", "f0", "alpha_t", "alpha_b", "phi")})
    np.testing.assert_allclose(np.sqrt(got["alpha_b"]), np.sqrt(want["alpha_b"]), atol=1 / 255 + 1e-6)
    np.testing.assert_allclose(got["alpha_t"], want["alpha_t"], atol=0.01)
    aniso = (want["alpha_t"] > 1.5 * want["alpha_b"])[:, 0]
    dphi = np.angle(np.exp(2j * (got["phi"] - want["phi"])))[aniso] / 2  # the axis, modulo π
    assert np.abs(dphi).max() < np.radians(1.0)
    assert np.median(maps["error"]) < 0.03


def test_anisotropic_round_trip_renders_like_the_original_through_gl(reg, anisotropic_export):
    """glTF read back, rendered by `gl` with tangent frames, against the source (stated: < 5 % mean)."""
    import dask.array as da

    from sbrdf_export.gltf import gltf_maps_to_ggx, read_gltf

    pytest.importorskip("moderngl")
    mat, p, maps, d, attrs = anisotropic_export
    back = gltf_maps_to_ggx(read_gltf(str(d / "material.gltf")))
    mat2 = Material(mat.model, {k: da.from_array(back[k]) for k in ("rho_d", "f0", "alpha_t", "alpha_b", "phi")},
                    mat.texels, mat.size_mm, "gltf")
    scene = d / "scene.yaml"
    scene.write_text(ROUND_TRIP_SCENE.format(w=64, h=48))
    try:
        r = reg.create("renderer", "gl", {"scene": str(scene)})
        a, b = np.asarray(r.render(mat).image), np.asarray(r.render(mat2).image)
    except Exception as e:  # no EGL on this machine
        if "EGL" in str(e) or "context" in str(e).lower():
            pytest.skip(f"no OpenGL context: {e}")
        raise
    rel = np.abs(a - b).sum() / np.abs(a).sum()
    assert a.max() > 0 and rel < 0.05
