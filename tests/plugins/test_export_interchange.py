"""The exr-set, materialx, usd and mitsuba exporters (plugins/sbrdf_export): files each tool loads itself."""

from __future__ import annotations

import importlib.util
import json
import textwrap

import numpy as np
import pytest

from sbrdf_core.graph import load_graph
from sbrdf_core.registry import Registry
from sbrdf_core.runner import Runner
from sbrdf_core.store import open_artifact

PLUGINS = ("sbrdf_export",)
#: Mitsuba's render of the exported scene against the cpu renderer's of the same scene file (relative RMS over
#: the lit pixels).  A cook-torrance GGX fit converts exactly (error 0), so what is left is Mitsuba's separable
#: Smith G and exact dielectric Fresnel against our height-correlated G and Schlick F (measured 0.009).
MITSUBA_TOLERANCE = 0.03
#: The UsdPreviewSurface fit of a cook-torrance GGX material: Storm's separable Smith-Schlick G, its ε and the
#: diffuse dimmed by 1 − F against our height-correlated G and undimmed diffuse.
USD_TOLERANCE = 0.05


def has(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def run(text: str):
    runner = Runner(registry=Registry(extra=PLUGINS), progress=False)
    return runner.run(load_graph(text, runner.registry))


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A cook-torrance fit of 8×6 texels exported by every exporter, and the cpu render of the Mitsuba scene."""
    from sbrdf_export.mitsuba import DEFAULT_SCENE

    tmp = tmp_path_factory.mktemp("export")
    scene = tmp / "scene.yaml"
    scene.write_text(DEFAULT_SCENE.format(w=96, h=72, sy=1.5))
    nodes = {"exr": "exr-set"}
    if has("MaterialX"):
        nodes["mtlx"] = "materialx"
    if has("pxr"):
        nodes["usd"] = "usd"
    exports = "".join(f"  {n}: {{kind: Export, plugin: {p}, in: {{material: fit}}}}\n" for n, p in nodes.items())
    run(textwrap.dedent(f"""\
        name: export
        store: {tmp / 's'}
        nodes:
          a: {{kind: SampleModel, params: {{model: cook-torrance, texels: [8, 6], poses: 60, seed: 3}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: a}}, params: {{model: cook-torrance}}}}
          mitsuba: {{kind: Export, plugin: mitsuba, in: {{material: fit}}, params: {{scene: {scene}}}}}
          cpu: {{kind: Render, plugin: cpu, in: {{material: fit}}, params: {{scene: {scene}}}}}
        """) + exports)
    return tmp / "s"


def test_exr_set_holds_the_models_own_maps_and_a_sidecar(store):
    from sbrdf_export.exr_set import read_exr_set

    art = open_artifact(f"{store}/exr")
    fit = open_artifact(f"{store}/fit")
    assert art.attrs["exporter"] == "exr-set" and "error_mean" not in art.attrs
    assert sorted(art.attrs["files"]) == ["alpha.exr", "brdf.glsl", "f0.exr", "material.json", "rho_d.exr"]
    maps, desc = read_exr_set(f"{store}/exr")
    for name in ("rho_d", "f0", "alpha"):
        np.testing.assert_array_equal(maps[name], fit.read(f"params/{name}").astype(np.float32))
    assert desc["model"] == "cook-torrance" and desc["model_config"] == {"distribution": "ggx"}
    assert desc["texels"] == [8, 6] and desc["size_mm"] == [100.0, 100.0]
    units = {f["parameter"]: (f["unit"], f["channels"]) for f in desc["files"]}
    assert units == {"rho_d": ("sr^-1", ["R", "G", "B"]), "f0": ("1", ["R", "G", "B"]), "alpha": ("", ["Y"])}
    assert "brdf_cook_torrance" in (store / "exr" / "brdf.glsl").read_text()
    json.loads((store / "exr" / "material.json").read_text())


@pytest.mark.skipif(not has("MaterialX"), reason="MaterialX is not installed (pip install materialx)")
def test_materialx_document_validates_with_materialx_and_reads_the_glTF_maps(store):
    import MaterialX as mx

    from sbrdf_export.materialx import validate

    art = open_artifact(f"{store}/mtlx")
    assert art.attrs["validated"] and art.attrs["error_max"] < 0.05  # cook-torrance GGX: glTF reads it closely
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(store / "mtlx" / "material.mtlx"))
    ok, message = validate(mx, doc)
    assert ok, message
    materials = doc.getMaterialNodes()
    assert [m.getName() for m in materials] == ["M_sbrdf"]
    shader = mx.getShaderNodes(materials[0])[0]
    assert shader.getCategory() == "standard_surface"
    for name, file in (("base_color", "base_color.exr"), ("specular_roughness", "roughness.exr")):
        inp = shader.getInput(name)
        out = doc.getNodeGraph(inp.getNodeGraphString()).getOutput(inp.getOutputString())
        image = out.getConnectedNode()
        assert image.getCategory() == "image" and image.getInputValue("file") == file
        assert (store / "mtlx" / file).exists()
    # the texture is the stored map, rows bottom-up
    from sbrdf_core.io import read_exr

    np.testing.assert_allclose(read_exr(str(store / "mtlx" / "base_color.exr"))[::-1], art.read("maps/base_color"),
                               rtol=1e-6)


@pytest.mark.skipif(not has("pxr"), reason="usd-core is not installed (pip install usd-core)")
def test_usd_stage_opens_binds_the_material_and_its_inputs_read_back(store):
    from pxr import Usd, UsdGeom, UsdShade

    from sbrdf_core.io import read_png

    art = open_artifact(f"{store}/usd")
    stage = Usd.Stage.Open(str(store / "usd" / "material.usda"))
    assert stage is not None and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    mesh = stage.GetPrimAtPath("/Sample/Plane")
    material, _ = UsdShade.MaterialBindingAPI(mesh).ComputeBoundMaterial()
    assert material.GetPath() == "/Sample/Looks/Material"
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
    assert surface.GetInput("useSpecularWorkflow").Get() == 1
    for name, file in (("diffuseColor", "diffuse_color.png"), ("specularColor", "specular_color.png"),
                       ("roughness", "roughness.png")):
        source = surface.GetInput(name).GetConnectedSources()[0][0].source
        tex = UsdShade.Shader(source.GetPrim())
        assert tex.GetIdAttr().Get() == "UsdUVTexture"
        asset = tex.GetInput("file").Get()
        assert asset.path == f"./{file}" and (store / "usd" / file).exists()
        st = tex.GetInput("st").GetConnectedSources()[0][0].source
        assert UsdShade.Shader(st.GetPrim()).GetIdAttr().Get() == "UsdPrimvarReader_float2"
    rough = read_png(str(store / "usd" / "roughness.png"))[::-1].astype(np.float64) / 65535
    np.testing.assert_allclose(rough, art.read("maps/roughness")[..., 0], atol=1e-4)
    ior = surface.GetInput("ior").GetConnectedSources()[0][0].source
    tex = UsdShade.Shader(ior.GetPrim())
    assert tex.GetInput("scale").Get()[0] == pytest.approx(18.0) and tex.GetInput("bias").Get()[0] == 1.0
    # USD shades GGX with separable Smith-Schlick G and dims the diffuse by 1 - F: close to ours, not equal
    assert art.attrs["error_max"] < USD_TOLERANCE


def usd_validation_errors(stage) -> list[str]:
    """Every registered UsdValidation validator run on ``stage``: ``["name: message", ...]``."""
    from pxr import UsdValidation

    registry = UsdValidation.ValidationRegistry()
    errors = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators()).Validate(stage)
    return [f"{e.GetName()}: {e.GetMessage()}" for e in errors]


@pytest.mark.skipif(not has("pxr"), reason="usd-core is not installed (pip install usd-core)")
def test_usd_stage_passes_usds_own_validators(store, tmp_path):
    from pxr import Sdf, Usd, UsdShade

    assert usd_validation_errors(Usd.Stage.Open(str(store / "usd" / "material.usda"))) == []
    # the validators are live: the token-typed varname USD exports used to write is reported
    stage = Usd.Stage.CreateNew(str(tmp_path / "token.usda"))
    reader = UsdShade.Shader.Define(stage, "/M/stReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    assert any("varname" in e for e in usd_validation_errors(stage))


@pytest.mark.skipif(not has("MaterialX"), reason="MaterialX is not installed (pip install materialx)")
def test_materialx_inputs_stay_in_standard_surface_ranges(store):
    from sbrdf_core.io import read_exr

    d = store / "mtlx"
    tint, ior = read_exr(str(d / "specular_tint.exr")), read_exr(str(d / "specular_ior.exr"))
    assert tint.min() >= 0 and tint.max() <= 1 + 1e-6  # specular_color is a tint in [0, 1], not glTF's up-to-25
    assert ior.min() >= 1.0 and np.isfinite(ior).all()
    art = open_artifact(str(d))
    # normal incidence: specular x tint x F(IOR) is glTF's min(0.04 specularColor, 1) x specularFactor
    f0_ior = ((ior[..., :1] - 1) / (ior[..., :1] + 1)) ** 2
    want = np.minimum(0.04 * art.read("maps/specular_color"), 1.0)
    np.testing.assert_allclose((tint * f0_ior)[::-1], want, atol=2e-3)


def test_validate_reports_a_missing_extra_before_anything_runs(monkeypatch):
    """`sbrdf validate graphs/export-interchange.yaml` without MaterialX: the node, the line and the install command."""
    from pathlib import Path

    from sbrdf_core.errors import GraphError

    graph = Path(__file__).resolve().parents[2] / "graphs" / "export-interchange.yaml"
    if has("MaterialX") and has("pxr"):
        load_graph(graph, Registry(extra=PLUGINS))  # valid where the extra is installed
    monkeypatch.setitem(__import__("sys").modules, "MaterialX", None)  # Python's own "not importable" marker
    with pytest.raises(GraphError) as e:
        load_graph(graph, Registry(extra=PLUGINS))
    message = str(e.value)
    assert "export-interchange.yaml:21: node 'materialx'" in message
    assert "pip install 'sbrdf[interchange]'" in message and "'usd'" not in message


@pytest.mark.skipif(not has("mitsuba"), reason="mitsuba is not installed (pip install mitsuba); CI installs it")
def test_mitsuba_renders_the_exported_scene_like_the_cpu_renderer(store):
    from sbrdf_export.mitsuba import render

    art = open_artifact(f"{store}/mitsuba")
    assert {"scene.xml", "blend_diffuse.exr", "eta.exr", "alpha.exr"} <= set(art.attrs["files"])
    image = render(str(store / "mitsuba" / "scene.xml"))
    cpu = open_artifact(f"{store}/cpu").read("image")
    assert image.shape == cpu.shape == (72, 96, 3)
    lit = cpu.max(-1) > 0
    assert lit.mean() > 0.4
    err = float(np.sqrt(((image - cpu) ** 2)[lit].mean() / (cpu ** 2)[lit].mean()))
    assert err < MITSUBA_TOLERANCE, err
    assert np.abs(image[~lit]).max() < 1e-6  # nothing where the cpu renderer sees nothing


@pytest.mark.parametrize("name", ["exr-set", "materialx", "usd", "mitsuba"])
def test_exporters_follow_the_contract(name):
    from sbrdf_core.testing import PluginTests

    class Suite(PluginTests):
        category = "exporter"
        plugins = PLUGINS

    Suite.name = name
    suite = Suite()
    suite.test_implements_its_protocol()
    suite.test_declared_parameters_match_the_constructor()
    suite.test_every_declared_parameter_is_documented()


def test_mitsuba_scene_refuses_what_it_cannot_translate(tmp_path):
    import dask.array as da

    from sbrdf_core.nodes.render import Material
    from sbrdf_export.mitsuba import MitsubaExporter

    reg = Registry(extra=PLUGINS)
    model = reg.create("brdf-model", "lambert", {})
    material = Material(model, {"rho_d": da.full((2, 2, 3), 0.1)}, (2, 2), (10.0, 10.0), "memory://x")
    scene = tmp_path / "s.yaml"
    scene.write_text("camera: {position: [0, -2, 2], look_at: [0, 0, 0], fov_deg: 40, resolution: [8, 8]}\n"
                     "materials: {sample: {artifact: input}}\n"
                     "objects: [{shape: cylinder, radius: 0.3, height: 0.5}]\n"
                     "lights: [{type: point, position: [0, 0, 2], intensity: 1}]\n")
    exporter = MitsubaExporter(scene=str(scene))
    exporter.bind(reg)
    with pytest.raises(ValueError, match="cylinder"):
        exporter.scene_xml(str(scene), material)
    scene.write_text(scene.read_text().replace("shape: cylinder, radius: 0.3, height: 0.5", "shape: plane")
                     .replace("intensity: 1}", "intensity: 1, falloff: false}"))
    with pytest.raises(ValueError, match="falloff"):
        exporter.scene_xml(str(scene), material)
