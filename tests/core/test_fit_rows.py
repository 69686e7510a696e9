"""Fit tasks sized from bytes: a tile fitted in strips of rows gives the maps the whole tile gives.

The Fit node splits a stored tile into strips of rows when the tile's samples are over its memory
budget (``sbrdf_core.nodes.fit.fit_block``), so its memory per task stays flat in the number of poses.
A strip reads its neighbours' rows and the tile's held-out stream at its rows, so the maps are the
same bits: checked here with a budget small enough for 2-row strips, with held-out samples, physical
bounds and sparse texels that borrow their neighbours' samples (a seeded mask of mostly invalid texels).
Without ``coherence``: a strip sees fewer neighbours' solutions than the whole tile, so with it the two may
differ where a neighbour's solution was taken.
"""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.graph import load_graph
from sbrdf_core.nodes import fit as fit_node
from sbrdf_core.runner import Runner
from sbrdf_core.store import open_artifact

GRAPH = """\
name: rows
store: {store}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [12, 10], poses: 16, noise: 0.02, seed: 4,
             model: {model}, saturation: {saturation}}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}, params: {{tile: 8}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: {model}, iterations: 30,
         min_samples: 6, coherence: none}}}}
"""


def test_fit_block_is_chosen_from_bytes():
    # the same samples per task (within one row's) at 4x and 16x the poses
    per_task = [fit_node.fit_block(P, (t, t)) * t * P for P, t in ((136, 64), (543, 32), (2170, 16))]
    assert max(per_task) / min(per_task) < 1.1
    assert fit_node.fit_block(60, (64, 64)) == 64  # a small scan's tile is one task
    assert fit_node.fit_block(10**7, (8, 8)) == 1  # never less than a row


@pytest.mark.parametrize("model", ["lambert", pytest.param("lafortune", marks=pytest.mark.slow)])
def test_strips_of_rows_fit_what_the_whole_tile_fits(tmp_path, registry, monkeypatch, model):
    g = tmp_path / "g.yaml"
    g.write_text(GRAPH.format(store=tmp_path / "whole", model=model, saturation=0.1))
    runner = Runner(registry)
    runner.run(load_graph(str(g), registry))
    whole = open_artifact(str(tmp_path / "whole" / "fit"))
    # 2 rows of an 8-wide tile of 16 poses per task
    monkeypatch.setattr(fit_node, "FIT_TASK_BYTES", 2 * 8 * 16 * fit_node.FIT_SAMPLE_BYTES)
    assert fit_node.fit_block(16, (8, 8)) == 2
    g.write_text(GRAPH.format(store=tmp_path / "rows", model=model, saturation=0.1))
    runner.run(load_graph(str(g), registry))
    rows = open_artifact(str(tmp_path / "rows" / "fit"))
    flags = whole.read("flags")
    assert (flags & fit_node.BORROWED).any() and np.isfinite(whole.read("rms_holdout")).any()
    for name in whole.names():
        if name != "fit_time_s" and not name.startswith("_"):
            a, b = whole.read(name), rows.read(name)
            assert a.tobytes() == b.tobytes(), name
