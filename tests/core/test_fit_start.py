"""The Fit node's ``start`` input: a larger model never ends above the smaller fit it is given."""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_core.graph import load_graph
from sbrdf_core.nodes import fit as fit_node
from sbrdf_core.runner import Runner
from sbrdf_core.store import open_artifact

GRAPH = """\
name: start
store: {store}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [10, 8], poses: 40, noise: 0.02, seed: 3,
             model: lafortune, model_params: {{lobes: 1}}}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}, params: {{tile: 8}}}}
  small: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lafortune,
           model_params: {{lobes: 1}}}}}}
  large: {{kind: Fit, plugin: lm, in: {{samples: reflectance{start}}}, params: {{model: lafortune,
           model_params: {{lobes: {lobes}}}, iterations: 1, starts: 1, coherence: none}}}}
"""


def _rms(store, node):
    return np.asarray(open_artifact(str(store / node)).read("rms"), np.float64)


def test_a_larger_model_never_ends_above_its_start(tmp_path, registry, monkeypatch):
    # one LM iteration leaves the 2-lobe fit far from its minimum: alone it ends above the 1-lobe fit
    runner = Runner(registry, progress=False)
    g = tmp_path / "g.yaml"
    g.write_text(GRAPH.format(store=tmp_path / "alone", start="", lobes=2))
    runner.run(load_graph(str(g), registry))
    small, alone = _rms(tmp_path / "alone", "small"), _rms(tmp_path / "alone", "large")
    assert (alone > small * (1 + 1e-6)).sum() > 5
    # given the 1-lobe maps, whole tiles and strips of rows (the two ways a task reads them) never do
    for name, budget in (("tiles", None), ("rows", 2 * 8 * 40 * fit_node.FIT_SAMPLE_BYTES)):
        if budget is not None:
            monkeypatch.setattr(fit_node, "FIT_TASK_BYTES", budget)
        g.write_text(GRAPH.format(store=tmp_path / name, start=", start: small", lobes=3))
        runner.run(load_graph(str(g), registry))
        small, large = _rms(tmp_path / name, "small"), _rms(tmp_path / name, "large")
        assert np.all(large <= small * (1 + 1e-6) + 1e-9)
        assert (large < small * (1 - 1e-3)).any()  # and its own fit is kept where it is better
        # both scored on the same held-out samples: the split reads no model
        held = [np.isfinite(open_artifact(str(tmp_path / name / n)).read("rms_holdout")) for n in ("small", "large")]
        assert held[0].any() and np.array_equal(*held)


def test_a_start_of_another_model_is_refused_with_both_named(tmp_path, registry):
    text = GRAPH.format(store=tmp_path / "s", start=", start: small", lobes=2).replace(
        "model: lafortune,\n           model_params: {lobes: 1}", "model: ward")
    g = tmp_path / "g.yaml"
    g.write_text(text)
    with pytest.raises(SbrdfError, match=r"node 'large'.*ward.*lafortune"):
        Runner(registry, progress=False).run(load_graph(str(g), registry))
    assert not (tmp_path / "s" / "large").exists()
