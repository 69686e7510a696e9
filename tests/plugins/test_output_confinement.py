"""Plugin output paths (the separable fitters' ``factors``) stay inside the store, beside the artifacts.

Every case outside the store checks a sentinel folder of files with content:
its full listing and every file's bytes must be unchanged afterwards.
"""

from __future__ import annotations

import logging
import os
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sbrdf_core.errors import GraphError, SbrdfError
from sbrdf_core.graph import load_graph
from sbrdf_core.outputs import OutputPathError
from sbrdf_core.registry import Registry
from sbrdf_core.runner import Runner
from sbrdf_separable.factors import Factors, load, save

REGISTRY = Registry()

GRAPH = textwrap.dedent("""\
    name: confine
    store: {store}
    {extra}nodes:
      material: {{kind: SampleModel, params: {{model: ward, params: {{rho_d: 0.3, rho_s: 0.2, alpha: 0.2}},
                  texels: [1, 1], size_mm: [0.001, 0.001], poses: 400, directions: random}}}}
      nd:
        kind: Fit
        plugin: nd
        in: {{samples: material}}
        params: {{factors: '{factors}', size: 8, holdout: 0}}
    """)
FACTORS_LINE = 10  # the line of the nd node's params in GRAPH (without an extra line)


def snapshot(root: Path) -> dict[str, bytes | str]:
    """Every entry below ``root``: file bytes, directory marker, or link target."""
    out: dict[str, bytes | str] = {}
    for dirpath, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(dirpath) / name
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = "link:" + os.readlink(p)
            elif p.is_dir():
                out[rel] = "dir"
            else:
                out[rel] = p.read_bytes()
    return out


@pytest.fixture
def sentinel(tmp_path):
    root = tmp_path / "sentinel"
    (root / "sub").mkdir(parents=True)
    (root / "keep.txt").write_text("precious\n")
    (root / "sub" / "data.bin").write_bytes(bytes(range(256)))
    return root


def write_graph(tmp_path, factors, extra="") -> Path:
    g = tmp_path / "graph.yaml"
    g.write_text(GRAPH.format(store=tmp_path / "store", factors=factors, extra=extra))
    return g


def refused(graph: Path, *needles: str) -> GraphError:
    with pytest.raises(GraphError) as e:
        load_graph(graph, REGISTRY)
    text = str(e.value)
    for n in needles:
        assert n in text, text
    return e.value


def tiny_factors() -> Factors:
    rng = np.random.default_rng(0)
    return Factors(rng.random((1, 4, 4, 3)), rng.random((1, 4, 4, 3)), "gram-schmidt", {"map": "xy"})


# -- validation --------------------------------------------------------------------------------------------------


def test_an_existing_folder_outside_the_store_is_refused_at_validation(tmp_path, sentinel):
    before = snapshot(sentinel)
    refused(write_graph(tmp_path, sentinel), f"graph.yaml:{FACTORS_LINE}:", "parameter 'factors'",
            "outside the store", "allow_outside_store")
    refused(write_graph(tmp_path, sentinel / "keep.txt"), f"graph.yaml:{FACTORS_LINE}:", "outside the store")
    refused(write_graph(tmp_path, sentinel / "new.zarr"), "outside the store")
    assert snapshot(sentinel) == before


def test_the_store_root_another_nodes_artifact_and_store_files_are_refused(tmp_path):
    store = tmp_path / "store"
    refused(write_graph(tmp_path, store), f"graph.yaml:{FACTORS_LINE}:", "is the store root")
    refused(write_graph(tmp_path, store / "material"), "inside node 'material'")
    refused(write_graph(tmp_path, store / "material" / "f.zarr"), "inside node 'material'")
    refused(write_graph(tmp_path, store / "nd" / "f.zarr"), "inside node 'nd'")
    refused(write_graph(tmp_path, store / ".sbrdf.lock"), "store's own file")
    refused(write_graph(tmp_path, store / "sub" / ".." / ".." / "out.zarr"), "outside the store")


def test_a_link_in_the_store_leading_out_of_it_is_refused(tmp_path, sentinel):
    store = tmp_path / "store"
    store.mkdir()
    (store / "out").symlink_to(sentinel)
    before = snapshot(sentinel)
    refused(write_graph(tmp_path, store / "out" / "f.zarr"), "outside the store", str(sentinel.resolve()))
    assert snapshot(sentinel) == before


def test_a_foreign_artifact_directory_in_the_store_is_refused(tmp_path):
    foreign = tmp_path / "store" / "old_node"
    foreign.mkdir(parents=True)
    (foreign / ".sbrdf-artifact").write_text('{"node": "old_node", "kind": "ParamMaps"}')
    refused(write_graph(tmp_path, foreign / "f.zarr"), "lies inside the artifact directory")
    refused(write_graph(tmp_path, foreign), "is the artifact directory")  # another graph's node, same store


def test_two_nodes_writing_one_path_are_refused(tmp_path):
    g = write_graph(tmp_path, tmp_path / "store" / "f.zarr")
    g.write_text(g.read_text() + "  svd:\n    kind: Fit\n    plugin: svd\n    in: {samples: material}\n"
                 f"    params: {{factors: '{tmp_path / 'store' / 'f.zarr'}', size: 8}}\n")
    refused(g, "node 'svd': parameter 'factors'", "is also written by node 'nd'", f"line {FACTORS_LINE}")


def test_a_path_beside_the_artifacts_is_valid(tmp_path):
    g = load_graph(write_graph(tmp_path, "store/ward.zarr"), REGISTRY)
    assert g.nodes["nd"].params["factors"] == str(tmp_path / "store" / "ward.zarr")


def test_the_opt_in_lets_listed_folders_out_and_validate_says_so(tmp_path, sentinel, caplog):
    out = tmp_path / "exports"
    out.mkdir()
    g = write_graph(tmp_path, out / "ward.zarr", extra="allow_outside_store: [exports]\n")
    with caplog.at_level(logging.WARNING, logger="sbrdf_core.graph"):
        load_graph(g, REGISTRY)
    assert "outside the store: allowed by 'allow_outside_store' (line 3)" in caplog.text
    # a folder not listed is still refused, and the opt-in never opens the store root or an artifact
    refused(write_graph(tmp_path, sentinel, extra="allow_outside_store: [exports]\n"), "outside the store")
    refused(write_graph(tmp_path, tmp_path / "store", extra="allow_outside_store: true\n"), "is the store root")
    refused(write_graph(tmp_path, tmp_path / "store" / "material", extra="allow_outside_store: true\n"),
            "inside node 'material'")
    refused(write_graph(tmp_path, out / "w.zarr", extra="allow_outside_store: 3\n"), "graph.yaml:3:",
            "'allow_outside_store' must be")


# -- run time: save() replaces only what it wrote ----------------------------------------------------------------


def test_save_never_replaces_what_it_did_not_write(tmp_path, sentinel):
    before = snapshot(sentinel)
    for target in (sentinel, sentinel / "keep.txt", sentinel / "sub"):
        with pytest.raises(OutputPathError, match="refusing to replace it"):
            save(tiny_factors(), str(target))
    link = tmp_path / "link.zarr"
    link.symlink_to(sentinel)
    with pytest.raises(OutputPathError, match="symbolic link"):
        save(tiny_factors(), str(link))
    assert snapshot(sentinel) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.zarr", "sentinel"]  # no temporary left behind

    mine = tmp_path / "mine.zarr"
    save(tiny_factors(), str(mine))
    second = tiny_factors()
    second.g *= 2
    save(second, str(mine))  # its own store: replaced
    np.testing.assert_allclose(load(str(mine)).g, second.g, rtol=1e-6)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.zarr", "mine.zarr", "sentinel"]


def test_save_refuses_store_roots_and_artifacts(tmp_path):
    store = tmp_path / "store"
    (store / "fit").mkdir(parents=True)
    (store / ".sbrdf.lock").write_text("")
    (store / "fit" / ".sbrdf-artifact").write_text('{"node": "fit", "kind": "ParamMaps"}')
    before = snapshot(store)
    with pytest.raises(OutputPathError, match="store root"):
        save(tiny_factors(), str(store))
    with pytest.raises(OutputPathError, match="artifact directory"):
        save(tiny_factors(), str(store / "fit"))
    with pytest.raises(OutputPathError, match="inside the artifact directory"):
        save(tiny_factors(), str(store / "fit" / "f.zarr"))
    assert snapshot(store) == before
    save(tiny_factors(), str(store / "f.zarr"))  # beside the artifacts: fine


def _python_graph(tmp_path, factors):
    """A valid graph whose factors path is then changed in Python, as a graph built in code would be (no
    validation): what the run itself must refuse."""
    g = load_graph(write_graph(tmp_path, "store/ok.zarr"), REGISTRY)
    g.nodes["nd"].params["factors"] = str(factors)
    return g


@pytest.mark.parametrize("where", ["sentinel", "file", "store", "artifact"])
def test_a_run_never_deletes_or_replaces_what_it_did_not_write(tmp_path, sentinel, where):
    store = tmp_path / "store"
    runner = Runner(progress=False)
    runner.run(load_graph(write_graph(tmp_path, "store/ok.zarr"), REGISTRY), only=["material"])
    target = {"sentinel": sentinel, "file": sentinel / "keep.txt", "store": store,
              "artifact": store / "material"}[where]
    before, store_before = snapshot(sentinel), snapshot(store)
    with pytest.raises(SbrdfError) as e:
        runner.run(_python_graph(tmp_path, target))
    assert str(target) in str(e.value)
    assert snapshot(sentinel) == before
    after = snapshot(store)
    assert all(after.get(k) == v for k, v in store_before.items() if not k.startswith(".sbrdf.lock"))


def test_a_graph_run_writes_its_factors_beside_the_artifacts_and_again_on_a_rerun(tmp_path):
    g = write_graph(tmp_path, "store/ward.zarr")
    Runner(progress=False).run(load_graph(g, REGISTRY))
    first = load(str(tmp_path / "store" / "ward.zarr")).g
    g.write_text(g.read_text().replace("size: 8", "size: 6"))
    Runner(progress=False).run(load_graph(g, REGISTRY))  # replaces its own factor store
    assert load(str(tmp_path / "store" / "ward.zarr")).g.shape[1] == 6 != first.shape[1]


def test_a_graph_built_in_python_cannot_create_an_output_outside_the_store(tmp_path, sentinel):
    """Validation is skipped for a graph edited in code; the runner applies the same rule before the plugin runs."""
    runner = Runner(progress=False)
    new = sentinel / "new.zarr"
    with pytest.raises(SbrdfError, match="outside the store") as e:
        runner.run(_python_graph(tmp_path, new))
    assert "parameter 'factors'" in str(e.value) and not new.exists()
    g = _python_graph(tmp_path, new)
    g.outside_store = (False, (str(sentinel),))  # what a top-level allow_outside_store: [<sentinel>] gives
    runner.run(g)
    assert (new / "zarr.json").exists()
