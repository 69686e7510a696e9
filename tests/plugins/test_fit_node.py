"""The Fit node end to end: SampleModel -> Fit on real zarr stores, flags, summaries and the Table 3.4 row."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from sbrdf_core.cli import main
from sbrdf_core.errors import GraphError
from sbrdf_core.graph import load_graph
from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact

GRAPH = textwrap.dedent("""\
    name: fit-node
    store: {store}
    nodes:
      samples: {{kind: SampleModel, params: {{model: lafortune, model_params: {{lobes: 1}}, texels: [12, 10], poses: 300,
                noise: 0.001, tile: 8}}}}
      lm: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lafortune}}}}
      mc: {{kind: Fit, plugin: mcallister, in: {{samples: samples}}}}
      ls: {{kind: Fit, plugin: line-search, in: {{samples: samples}}}}
    """)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    store = tmp_path_factory.mktemp("fit") / "store"
    report = run_graph(GRAPH.format(store=store), progress=False)
    return store, report


def test_sample_model_stores_samples_and_truth(fitted):
    store, _ = fitted
    art = open_artifact(f"{store}/samples")
    f, valid = art.read("f_r"), art.read("valid")
    assert f.shape == (10, 12, 300, 3) and valid.any()
    assert np.isfinite(f).all() and (f[~valid] == 0).all()
    truth = {n.split("/", 1)[1]: art.read(n) for n in art.names() if n.startswith("truth/")}
    assert set(truth) == {"rho_d", "rho_s_1", "c_xy_1", "c_z_1", "exponent_1"}


def test_fit_recovers_the_sampled_material(fitted, registry):
    store, _ = fitted
    samples = open_artifact(f"{store}/samples")
    model = registry.create("brdf-model", "lafortune", {"lobes": 1})
    truth = model.canonical({k.split("/", 1)[1]: samples.read(k).reshape(-1, samples.read(k).shape[-1]).astype(float)
                             for k in samples.names() if k.startswith("truth/")})
    lm = open_artifact(f"{store}/lm")
    fit = model.canonical({k.split("/", 1)[1]: lm.read(k).reshape(-1, lm.read(k).shape[-1]).astype(float)
                           for k in lm.names() if k.startswith("params/")})
    assert np.median(np.abs(np.log(fit["exponent_1"] / truth["exponent_1"]))) < 0.1
    assert np.median(lm.read("rms")) < 1.2e-3  # the noise floor is 1e-3


def test_maps_flags_time_and_summary(fitted):
    store, _ = fitted
    for node in ("lm", "mc", "ls"):
        art = open_artifact(f"{store}/{node}")
        assert art.read("flags").dtype == np.uint16 and art.read("flags").shape == (10, 12)
        assert (art.read("fit_time_s") > 0).all()
        s = art.attrs["summary"]
        assert s["rms_mean"] > 0 and s["rms_max"] >= s["rms_mean"] and s["fit_time_s"] > 0
        assert art.attrs["flag_bits"]["1"].startswith("no valid samples")
        assert art.attrs["fitter"] == {"lm": "lm", "mc": "mcallister", "ls": "line-search"}[node]


def test_info_prints_a_table_3_4_row_per_fitter(fitted, capsys):
    store, _ = fitted
    assert main(["info", str(store)]) == 0
    out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.startswith("artifact") and "avg_rms" in line)
    assert "fit_s" in header and "max_rms" in header
    rows = {line.split()[0]: line.split() for line in out.splitlines()[out.splitlines().index(header) + 2:]}
    assert set(rows) == {"lm", "mc", "ls"}
    assert rows["ls"][1] == "line-search" and float(rows["lm"][-3]) < float(rows["ls"][-3])  # avg RMS: LM beats LS


def test_graph_names_the_line_of_an_impossible_fitter_configuration(tmp_path, registry):
    text = GRAPH.format(store=tmp_path / "s").replace(
        "ls: {kind: Fit, plugin: line-search, in: {samples: samples}}",
        "ls: {kind: Fit, plugin: line-search, in: {samples: samples}, params: {model_params: {lobes: 2}}}")
    with pytest.raises(GraphError, match=r"graph.yaml:8: .*exactly one lobe") as err:
        path = tmp_path / "graph.yaml"
        path.write_text(text)
        load_graph(path, registry)
    assert "exactly one lobe" in str(err.value)


SELECT = textwrap.dedent("""\
    name: select
    store: {store}
    nodes:
      samples: {{kind: SampleModel, params: {{model: cook-torrance, texels: [8, 8], poses: 150, noise: 0.005,
                directions: random}}}}
      laf: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lafortune}}}}
      ct: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: cook-torrance}}}}
      best: {{kind: Select, in: {{a: laf, b: ct}}}}
    """)


def test_select_keeps_the_model_with_the_lowest_held_out_error(tmp_path):
    """Cook–Torrance data: the Cook–Torrance fit is kept, says why, and its held-out RMS is the noise level."""
    run_graph(SELECT.format(store=tmp_path / "s"), progress=False)
    best, ct = open_artifact(f"{tmp_path}/s/best"), open_artifact(f"{tmp_path}/s/ct")
    sel = best.attrs["selection"]
    assert sel["chosen"] == "b" and best.attrs["model"] == "cook-torrance"
    assert "held-out RMS" in sel["why"] and set(sel["candidates"]) == {"a", "b"}
    np.testing.assert_array_equal(best.read("params/alpha"), ct.read("params/alpha"))
    held = best.attrs["summary"]["rms_holdout_mean"]
    assert 0.004 < held < 0.007 < sel["candidates"]["a"]["score"]
