"""Quantize layouts end to end: SampleModel -> Fit -> Quantize (float-exr, fixed16, mcallister8, palette) on real stores."""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest

from sbrdf_core.errors import GraphError
from sbrdf_core.nodes.quantize import decode_texture_set
from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact

GRAPH = textwrap.dedent("""\
    name: quantize-layouts
    store: {store}
    nodes:
      samples: {{kind: SampleModel, params: {{model: lafortune, model_params: {{lobes: 1}}, texels: [16, 12], poses: 150,
                noise: 0.002, tile: 8, directions: random}}}}
      fit: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lafortune, model_params: {{lobes: 1}}}}}}
      f32: {{kind: Quantize, plugin: float-exr, in: {{params: fit, samples: samples}}, params: {{dtype: float32}}}}
      f16: {{kind: Quantize, plugin: float-exr, in: {{params: fit, samples: samples}}}}
      fx16: {{kind: Quantize, plugin: fixed16, in: {{params: fit, samples: samples}}}}
      hw8: {{kind: Quantize, plugin: mcallister8, in: {{params: fit, samples: samples}}}}
      hw8b: {{kind: Quantize, plugin: mcallister8, in: {{params: fit}}, params: {{rescale: balanced, c_range: 2.0}}}}
      pal: {{kind: Quantize, plugin: palette, in: {{params: fit, samples: samples}}, params: {{k: 16}}}}
      render: {{kind: Render, plugin: preview, in: {{material: hw8}}}}
    """)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    s = tmp_path_factory.mktemp("quantize") / "store"
    run_graph(GRAPH.format(store=s), progress=False)
    return s


def fitted(store, registry):
    fit = open_artifact(f"{store}/fit")
    return {k.split("/", 1)[1]: fit.read(k).astype(np.float64) for k in fit.names() if k.startswith("params/")}


def test_float32_round_trip_is_exact_and_costs_nothing(store, registry):
    params = fitted(store, registry)
    art = open_artifact(f"{store}/f32")
    decoded = decode_texture_set(art, registry)
    for k, v in params.items():
        assert np.array_equal(decoded[k], v), k
    assert art.attrs["added_rms"] == 0.0 and art.attrs["added_rms_own"] == 0.0
    assert art.attrs["bytes_per_texel"] == 4 * (3 + 3 + 1 + 1 + 1)


def test_material_exr_and_json_describe_and_decode_the_maps(store, registry):
    from sbrdf_quantizers.float_exr import read_material

    params = fitted(store, registry)
    art = open_artifact(f"{store}/f32")
    assert set(art.attrs["files"]) == {"material.exr", "material.json"}
    back, desc = read_material(art.url)
    for k, v in params.items():
        assert np.array_equal(back[k], v), k
    with open(f"{art.url}/material.json") as f:
        on_disk = json.load(f)
    assert on_disk == desc
    names = [c["name"] for c in desc["channels"]]
    assert names[:3] == ["rho_d.R", "rho_d.G", "rho_d.B"] and "exponent_1" in names
    assert {c["unit"] for c in desc["channels"] if c["parameter"].startswith("rho")} == {"sr^-1"}
    assert desc["colour_space"]["name"] == "mcallister" and desc["colour_space"]["encoding"] == "linear"
    half, hdesc = read_material(open_artifact(f"{store}/f16").url)
    assert {c["type"] for c in hdesc["channels"]} == {"half"}
    assert all(np.allclose(half[k], v, rtol=2 ** -10, atol=1e-7) for k, v in params.items())


def test_half_and_fixed16_are_bounded(store, registry):
    params = fitted(store, registry)
    f16 = open_artifact(f"{store}/f16")
    dec = decode_texture_set(f16, registry)
    for k, v in params.items():
        assert np.all(np.abs(dec[k] - v) <= 2 ** -11 * np.abs(v) + 6e-8), k  # half: 11 significant bits
    from sbrdf_quantizers.fixed16 import floor_parameters

    fx = open_artifact(f"{store}/fx16")
    dec = decode_texture_set(fx, registry)
    model = registry.create("brdf-model", "lafortune", {"lobes": 1})
    floors = floor_parameters(model)
    assert set(floors) == {"rho_d", "rho_s_1"}
    for k, v in params.items():
        step = fx.read(f"scale/{k}")
        if k.startswith("exponent"):  # stored as log n: a relative step
            assert np.all(np.abs(np.log(dec[k] / v)) <= step / 2 * 1.0001 + 1e-12), k
        elif k in floors:  # stored as log(x + ε)
            assert np.all(np.abs(np.log((dec[k] + floors[k]) / (v + floors[k]))) <= step / 2 * 1.0001 + 1e-12), k
        else:
            assert np.all(np.abs(dec[k] - v) <= step / 2 * 1.0001 + 1e-12), k
    assert f16.attrs["bytes_per_texel"] == fx.attrs["bytes_per_texel"] == 18
    assert 0 < f16.attrs["added_rms"] < 1e-3 and 0 < fx.attrs["added_rms"] < 1e-3


def test_hardware_layout_costs_most_and_stores_eleven_bytes(store, registry):
    hw = open_artifact(f"{store}/hw8")
    assert hw.attrs["bytes_per_texel"] == 4 + 3 + 4  # rho_d RGBA8, rho_s RGB8, (C_x, C_y, C_z, n') RGBA8
    assert {n for n in hw.names() if n.startswith("textures/")} == {"textures/rho_d", "textures/rho_s_1", "textures/lobe_1"}
    assert all(hw.read(n).dtype == np.uint8 for n in hw.names() if n.startswith("textures/"))
    assert (hw.read("textures/rho_d")[..., 3] == 255).all()  # alpha: opaque
    rms = {n: open_artifact(f"{store}/{n}").attrs["added_rms"] for n in ("f32", "f16", "fx16", "hw8")}
    assert rms["f32"] < rms["f16"] < rms["hw8"] and rms["fx16"] < rms["hw8"]
    own = open_artifact(f"{store}/hw8").read("error_own")
    assert own.shape == (12, 16) and np.isfinite(own).all() and (own > 0).any()
    dec = decode_texture_set(hw, registry)
    assert dec["exponent_1"].max() <= 255.0 and np.abs(dec["c_xy_1"]).max() <= 1.0


def test_hardware_rescale_strategies_and_the_wide_c_range(store, registry):
    b = open_artifact(f"{store}/hw8b")
    scale = b.read("scale/lobe_1")
    assert np.allclose(scale[:3], 2.0 / 128) and np.allclose(b.read("bias/lobe_1")[:3], -2.0)
    assert np.isfinite(b.read("error")).all()
    assert "error_own" not in b.names()  # no samples input: uniform-set error only


def test_render_node_reads_the_hardware_textures(store):
    img = open_artifact(f"{store}/render")
    assert img.attrs["finite"]


def test_mcallister8_rejects_models_it_cannot_store(tmp_path, registry):
    from sbrdf_quantizers.mcallister8 import McAllister8Quantizer

    q = McAllister8Quantizer()
    ward = registry.create("brdf-model", "ward", {})
    with pytest.raises(ValueError, match="Lafortune lobes"):
        q.encode({}, ward)
    aniso = registry.create("brdf-model", "lafortune", {"anisotropic": True, "beta": True})
    with pytest.raises(ValueError, match="no β channel"):
        q.encode({}, aniso)
    with pytest.raises(ValueError, match="c_range"):
        McAllister8Quantizer(c_range=3.0)


def test_mismatched_samples_are_a_clear_error(tmp_path):
    text = textwrap.dedent(f"""\
        name: mismatch
        store: {tmp_path / 's'}
        nodes:
          a: {{kind: SampleModel, params: {{model: lambert, texels: [8, 8], poses: 20}}}}
          b: {{kind: SampleModel, params: {{model: lambert, texels: [4, 4], poses: 20}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: a}}, params: {{model: lambert}}}}
          q: {{kind: Quantize, plugin: fixed16, in: {{params: fit, samples: b}}}}
        """)
    with pytest.raises(Exception, match="samples have 4×4 texels, params 8×8"):
        run_graph(text, progress=False)


def test_fixed16_works_for_other_models(tmp_path, registry):
    text = textwrap.dedent(f"""\
        name: ward16
        store: {tmp_path / 's'}
        nodes:
          a: {{kind: SampleModel, params: {{model: ward, texels: [8, 8], poses: 60}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: a}}, params: {{model: ward}}}}
          q: {{kind: Quantize, plugin: fixed16, in: {{params: fit, samples: a}}}}
        """)
    run_graph(text, progress=False)
    q = open_artifact(f"{tmp_path / 's'}/q")
    assert q.attrs["added_rms"] < 1e-3 and q.read("textures/alpha").dtype == np.uint16


def test_unknown_quantizer_parameter_is_reported_at_load(tmp_path):
    from sbrdf_core.graph import load_graph

    text = GRAPH.format(store=tmp_path / "s").replace("rescale: balanced", "rescale: median")
    with pytest.raises(GraphError, match="rescale"):
        load_graph(text)
