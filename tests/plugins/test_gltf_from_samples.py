"""gltf ``source: samples``: glTF's GGX fitted to the reflectance samples instead of converted from the fit."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_core.geometry import tile_directions
from sbrdf_core.graph import load_graph
from sbrdf_core.registry import Registry
from sbrdf_core.runner import Runner
from sbrdf_core.store import open_artifact
from sbrdf_lib import convert as cv


@pytest.fixture(scope="module")
def ggx():
    return cv.ggx_model(Registry())


def test_noise_free_ggx_samples_give_back_their_ggx(ggx):
    """Samples of glTF's own model (a dielectric: specular weight 1, F0 0.04) are fitted back to it."""
    wi, wo = cv.direction_pairs(max_theta_deg=70.0)
    T = 3
    wi, wo = np.broadcast_to(wi, (T,) + wi.shape), np.broadcast_to(wo, (T,) + wo.shape)
    truth = {"rho_d": np.full((T, 3), 0.1) * [1.0, 0.8, 0.6], "f0": np.full((T, 3), 0.04),
             "alpha": np.array([[0.05], [0.2], [0.6]])}
    f = ggx.eval(truth, wi, wo)
    valid = np.ones(wi.shape[:2], bool)
    valid[0, ::3] = False  # invalid samples carry garbage the fit must not see
    f[0, ::3] = np.nan
    gltf, err = cv.samples_to_gltf(f, valid, wi, wo, ggx)
    np.testing.assert_allclose(gltf["roughness"][:, 0] ** 2, truth["alpha"][:, 0], rtol=0.05)
    assert (err < 0.02).all()


def test_texels_without_samples_get_the_defaults_and_error_one(ggx):
    wi, wo = cv.direction_pairs(max_theta_deg=70.0)
    wi, wo = np.broadcast_to(wi, (2,) + wi.shape), np.broadcast_to(wo, (2,) + wo.shape)
    f = np.zeros(wi.shape)
    valid = np.zeros(wi.shape[:2], bool)
    valid[1] = True  # texel 1: measured black
    gltf, err = cv.samples_to_gltf(f, valid, wi, wo, ggx, iterations=2)
    assert err[0] == 1.0 and gltf["roughness"][0, 0] == 1.0
    assert err[1] == 0.0 and gltf["base_color"][1].max() == 0.0 and gltf["specular"][1, 0] == 0.0


def run(text: str, tmp_path):
    runner = Runner(registry=Registry(extra=("sbrdf_export",)), progress=False)
    runner.run(load_graph(textwrap.dedent(text).format(store=tmp_path / "s"), runner.registry))
    return tmp_path / "s"


GRAPH = """\
    name: from-samples
    store: {store}
    nodes:
      samples: {{kind: SampleModel, params: {{model: lafortune, params: {{exponent_1: 6.0}}, texels: [6, 4], poses: 120, seed: 4}}}}
      fit: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lafortune}}}}
      converted: {{kind: Export, plugin: gltf, in: {{material: fit}}}}
      fitted: {{kind: Export, plugin: gltf, in: {{material: fit, samples: samples}}, params: {{source: samples}}}}
    """


def test_export_fitted_to_samples_reproduces_them_better_than_the_conversion(tmp_path, ggx):
    """A broad Lafortune lobe (exponent 6): GGX fitted to its samples beats GGX converted from its fit, on them."""
    store = run(GRAPH, tmp_path)
    smp = open_artifact(f"{store}/samples")
    f, v = smp.read("f_r"), smp.read("valid")
    V, U = f.shape[:2]
    wi, _, wo = tile_directions(tuple(smp.attrs["texels"]), tuple(smp.attrs["size_mm"]), (0, V), (0, U),
                                smp.read("light_pos"), smp.read("camera_pos"))
    f, v = f.reshape(V * U, -1, 3).astype(np.float64), v.reshape(V * U, -1)
    v &= (wi[..., 2] >= np.cos(np.radians(70))) & (wo[..., 2] >= np.cos(np.radians(70)))
    errors = {}
    for node in ("converted", "fitted"):
        art = open_artifact(f"{store}/{node}")
        maps = {k: art.read(f"maps/{k}").reshape(V * U, -1).astype(np.float64) for k in cv.GLTF_MAPS}
        errors[node] = cv.sample_error(cv.gltf_brdf(ggx, maps, wi, wo), f, v, wi, wo)
    fitted = open_artifact(f"{store}/fitted")
    # the stored error of the samples path is this very measure
    np.testing.assert_allclose(fitted.read("error").reshape(-1), errors["fitted"], rtol=1e-3, atol=1e-5)
    assert np.median(errors["fitted"]) < 0.9 * np.median(errors["converted"])
    assert fitted.attrs["fitted_to"] == "samples" and open_artifact(f"{store}/converted").attrs["fitted_to"] == "params"
    assert (store / "fitted" / "material.gltf").exists()


def test_source_samples_without_the_samples_input_says_what_to_connect(tmp_path):
    text = GRAPH.replace("in: {{material: fit, samples: samples}}", "in: {{material: fit}}")
    with pytest.raises(SbrdfError, match="samples input"):
        run(text, tmp_path)


def test_samples_of_another_texel_grid_are_refused(tmp_path):
    text = GRAPH.replace("converted: {{kind: Export, plugin: gltf, in: {{material: fit}}}}",
                         "other: {{kind: SampleModel, params: {{model: lafortune, texels: [3, 2], poses: 40}}}}")
    text = text.replace("fit, samples: samples}}", "fit, samples: other}}")
    with pytest.raises(SbrdfError, match="texels"):
        run(text, tmp_path)
