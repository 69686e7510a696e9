"""The example third-party package (docs/examples/) works in a YAML graph like a built-in."""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.graph import load_graph
from sbrdf_core.runner import Runner
from sbrdf_core.store import open_artifact

from ..conftest import graph_yaml, synthetic_truth

pytest.importorskip("sbrdf_example", reason="install docs/examples/sbrdf-example-plugin (CI does)")


def test_minnaert_is_discovered_through_its_entry_point(registry):
    spec = registry.get("brdf-model", "minnaert")
    assert spec.distribution == "sbrdf-example-plugin" and spec.plugin == "example"


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
