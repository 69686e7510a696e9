"""Batches of scans: one store per scan, a failed scan reported without stopping the others, resume, discovery."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sbrdf_core.batch import Scan, run_batch, scans_from_csv, scans_from_dir
from sbrdf_core.cli import main
from sbrdf_core.errors import SbrdfError
from sbrdf_core.store import open_artifact

GRAPH = """\
name: "scan ${{scan}}"
description: "from ${{path}}"
store: {store}
variables:
  scan: ~
  path: none
  seed: 0
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [8, 6], poses: 6, noise: 0.01, seed: "${{seed}}"}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}, params: {{tile: 8}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lambert, iterations: 20,
         min_samples: 3}}}}  # 6 poses: hold 10 % out of texels with 6 samples or more
"""


@pytest.fixture
def batch(tmp_path, write_graph):
    graph = write_graph(GRAPH.format(store="runs"))
    csv = tmp_path / "scans.csv"
    csv.write_text("scan,seed\nfirst,1\nbroken,many\nthird,3\n")
    return graph, csv


def files(root):
    return {p: p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file() and p.name != "batch.json"}


def test_a_csv_batch_runs_one_store_per_scan_and_reports_a_broken_one(batch, tmp_path, registry):
    graph, csv = batch
    lines: list[str] = []
    report = run_batch(graph, scans_from_csv(csv), registry, echo=lines.append)
    assert [(s.scan, s.status) for s in report.scans] == [("first", "computed"), ("broken", "invalid"),
                                                         ("third", "computed")]
    root = tmp_path / "runs"
    assert report.root == str(root)
    assert {p.name for p in root.iterdir()} == {"first", "third", "batch.json"}
    broken = report.scans[1]
    assert f"{csv}:3: " in broken.error and "parameter 'seed' should be int, got str 'many' (from ${seed} = 'many')" \
        in broken.error
    # one line per scan start and finish; the invalid one says so at once
    assert lines[0].startswith("[2/3] broken: invalid, skipped:")
    assert "[1/3] first: started -> " in lines[1] and lines[2].startswith("[1/3] first: computed in ")
    assert "rms" in lines[2] and "held-out" in lines[2]
    # the summary table: status, node times, fit errors
    table = report.table()
    assert table.splitlines()[0].split() == ["scan", "status", "wall_s", "capture", "register", "reflectanc", "fit",
                                            "rms", "held_out"]
    assert "2 of 3 scans done, 1 failed" in table
    # each scan's graph got its own variables
    a, c = (open_artifact(str(root / s / "capture")) for s in ("first", "third"))
    assert a.provenance["parameters"]["seed"] == 1 and c.provenance["parameters"]["seed"] == 3
    assert a.provenance["graph"]["name"] == "scan first"
    fit = open_artifact(str(root / "first" / "fit")).attrs["summary"]
    assert report.scans[0].fits["fit"]["rms_mean"] == fit["rms_mean"]
    summary = json.loads((root / "batch.json").read_text())
    assert [s["status"] for s in summary["scans"]] == ["computed", "invalid", "computed"]
    assert summary["scans"][0]["nodes"]["fit"]["status"] == "computed"


def test_a_scan_that_fails_while_running_does_not_stop_the_others(tmp_path, write_graph, registry):
    graph = write_graph(GRAPH.format(store="runs"))
    scans = [Scan("a", {"scan": "a", "seed": "1"}), Scan("b", {"scan": "b", "seed": "2"}, store=str(tmp_path / "b")),
             Scan("c", {"scan": "c", "seed": "3"})]
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "capture").write_text("not an artifact")  # the run cannot write its capture there
    report = run_batch(graph, scans, registry, echo=None)
    assert [s.status for s in report.scans] == ["computed", "failed", "computed"]
    assert report.scans[1].error and report.failed == [report.scans[1]]


def test_rerunning_a_batch_recomputes_nothing(batch, tmp_path, capsys):
    graph, csv = batch
    assert main(["run", "-q", str(graph), "--batch", str(csv)]) == 1  # a scan is broken: exit status 1
    out = capsys.readouterr().out
    assert "first: computed" in out and "third: computed" in out and "broken: invalid" in out
    root = tmp_path / "runs"
    before = files(root)
    assert main(["run", "-q", str(graph), "--batch", str(csv)]) == 1
    out = capsys.readouterr().out
    assert "first: cached" in out and "third: cached" in out
    assert files(root) == before
    summary = json.loads((root / "batch.json").read_text())
    assert [s["status"] for s in summary["scans"]] == ["cached", "invalid", "cached"]
    # fix the broken row: only that scan computes
    csv.write_text("scan,seed\nfirst,1\nbroken,2\nthird,3\n")
    assert main(["run", "-q", str(graph), "--batch", str(csv)]) == 0
    out = capsys.readouterr().out
    assert "first: cached" in out and "broken: computed" in out and "third: cached" in out


def test_set_and_var_apply_to_every_scan_and_concurrent_scans_match(batch, tmp_path, registry):
    graph, csv = batch
    csv.write_text("scan,seed\nx,1\ny,2\n")
    one = run_batch(graph, scans_from_csv(csv), registry, store=str(tmp_path / "one"), echo=None,
                    overrides=["fit.params.iterations=10"])
    two = run_batch(graph, scans_from_csv(csv), registry, store=str(tmp_path / "two"), echo=None, concurrent=2,
                    overrides=["fit.params.iterations=10"])
    assert [s.status for s in one.scans + two.scans] == ["computed"] * 4
    for s in ("x", "y"):
        a = open_artifact(str(tmp_path / "one" / s / "fit"))
        b = open_artifact(str(tmp_path / "two" / s / "fit"))
        assert a.provenance["parameters"]["iterations"] == 10
        assert a.token == b.token and np.array_equal(a.read("params/rho_d"), b.read("params/rho_d"))


def test_a_folder_of_capture_folders_is_a_batch(tmp_path, write_graph, registry):
    scans = tmp_path / "scans"
    for name in ("tile-02", "tile-01", "notes"):
        (scans / name).mkdir(parents=True)
    for name in ("tile-01", "tile-02"):
        (scans / name / "capture.json").write_text("{}")
    found = scans_from_dir(scans)
    assert [(s.name, s.variables) for s in found] == [
        ("tile-01", {"scan": "tile-01", "path": str(scans / "tile-01")}),
        ("tile-02", {"scan": "tile-02", "path": str(scans / "tile-02")})]
    graph = write_graph(GRAPH.format(store="runs"))
    assert main(["run", "-q", str(graph), "--batch", str(scans), "--only", "capture"]) == 0
    art = open_artifact(str(tmp_path / "runs" / "tile-02" / "capture"))
    assert art.provenance["graph"]["name"] == "scan tile-02"
    with pytest.raises(SbrdfError, match="no capture folders here"):
        scans_from_dir(scans / "notes")


def test_csv_errors_name_the_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("scan,seed\na,1\nb\n")
    with pytest.raises(SbrdfError, match=r"bad.csv:3: 1 values for 2 columns"):
        scans_from_csv(bad)
    bad.write_text("scan,seed\na,1\na,2\n")
    with pytest.raises(SbrdfError, match=r"bad.csv:3: scan 'a' appears twice \(also .*bad.csv:2\)"):
        scans_from_csv(bad)
    bad.write_text("scan,seed,store\na,1,out/a\nb,2,\n")
    a, b = scans_from_csv(bad)
    assert a.store == str(tmp_path / "out" / "a") and b.store is None and a.variables == {"scan": "a", "seed": "1"}



def test_a_fifo_as_the_batch_csv_is_refused_without_blocking(tmp_path):
    import os

    fifo = tmp_path / "scans.csv"
    os.mkfifo(fifo)  # nothing ever writes to it: opening it for reading would block forever
    with pytest.raises(SbrdfError, match=r"scans.csv.*FIFO"):
        scans_from_csv(fifo)

def test_the_batch_root_may_not_use_a_per_scan_variable(tmp_path, write_graph, registry):
    graph = write_graph(GRAPH.format(store="runs/${scan}"))
    from sbrdf_core.errors import GraphError

    with pytest.raises(GraphError, match=r"variable \$\{scan\} has no value here"):
        run_batch(graph, [Scan("a", {"scan": "a"})], registry, echo=None)


@pytest.mark.slow
def test_a_batch_on_a_local_cluster_matches_the_scans_run_alone(tmp_path, write_graph, registry, cluster):
    """Three scans in flight at once on one distributed scheduler: their nodes have the same names, but each
    scan's keys name its artifact, so each scan's maps are its own, the same as the scan run alone on threads."""
    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner

    _, client = cluster
    graph = write_graph(GRAPH.format(store="runs"))
    scans = [Scan(f"s{i}", {"scan": f"s{i}", "seed": str(i)}) for i in (1, 2, 3)]
    lines: list[str] = []
    report = run_batch(graph, scans, registry, scheduler=client, concurrent=3, echo=lines.append)
    assert [s.status for s in report.scans] == ["computed"] * 3, [s.error for s in report.scans]
    assert not any(line.startswith("note:") for line in lines)
    for i in (1, 2, 3):
        alone = tmp_path / f"alone{i}"
        Runner(registry).run(load_graph(graph, registry, store=str(alone), variables={"scan": "x", "seed": str(i)}))
        a = open_artifact(str(tmp_path / "runs" / f"s{i}" / "fit")).read("params/rho_d")
        assert np.allclose(a, open_artifact(str(alone / "fit")).read("params/rho_d"), rtol=1e-5, atol=1e-7)


def test_set_store_moves_the_batch_root(batch, tmp_path, registry):
    graph, csv = batch
    csv.write_text("scan,seed\nx,1\n")
    report = run_batch(graph, scans_from_csv(csv), registry, echo=None, only=["capture"],
                       overrides=[f"store={tmp_path / 'elsewhere'}"])
    assert report.root == str(tmp_path / "elsewhere") and (tmp_path / "elsewhere" / "x" / "capture").is_dir()
    assert (tmp_path / "elsewhere" / "batch.json").is_file()


def test_the_scan_column_names_stores_even_where_the_graph_does_not_use_it(tmp_path, write_graph, registry):
    text = GRAPH.replace('name: "scan ${{scan}}"', "name: plain").replace("  scan: ~\n", "")
    graph = write_graph(text.format(store="runs"))
    csv = tmp_path / "scans.csv"
    csv.write_text("scan,seed,colour\nx,1,red\n")
    report = run_batch(graph, scans_from_csv(csv), registry, echo=None, only=["capture"])
    assert report.scans[0].status == "invalid"  # colour is no variable of the graph
    assert "variable 'colour', but the graph declares no such variable" in report.scans[0].error
    csv.write_text("scan,seed\nx,1\n")
    report = run_batch(graph, scans_from_csv(csv), registry, echo=None, only=["capture"])
    assert report.scans[0].status == "computed" and (tmp_path / "runs" / "x" / "capture").is_dir()
