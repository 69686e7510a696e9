"""The ``sbrdf`` command line, run as a real subprocess."""

from __future__ import annotations

import subprocess
import sys

from .conftest import graph_yaml


def sbrdf(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "sbrdf_core.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd)


def test_validate_run_info(write_graph, tmp_path):
    path = write_graph(graph_yaml(tmp_path / "s"))
    out = sbrdf("validate", path)
    assert out.returncode == 0 and "is valid: 6 nodes" in out.stdout
    out = sbrdf("run", "-q", path)
    assert out.returncode == 0, out.stderr
    assert "fit" in out.stdout and "computed" in out.stdout
    out = sbrdf("run", "-q", path)
    assert out.stdout.count("cached") == 6
    out = sbrdf("info", tmp_path / "s")
    assert out.returncode == 0
    for text in ("CaptureSet v1  complete", "ParamMaps v1  complete", "plugin lm sbrdf", "params/rho_d", "input samples: SampledReflectance"):
        assert text in out.stdout, text


def test_invalid_graph_exits_2_with_every_problem(write_graph, tmp_path):
    path = write_graph(graph_yaml(tmp_path / "s").replace("plugin: lm", "plugin: lmm").replace("kind: Quantize", "kind: Quantise"))
    out = sbrdf("run", path)
    assert out.returncode == 2
    assert f"{path}:7: node 'fit': unknown fitter plugin 'lmm'" in out.stderr
    assert f"{path}:8: node 'quantize': unknown node kind 'Quantise'" in out.stderr
    assert not (tmp_path / "s").exists()  # nothing ran, nothing was written


def test_plugins_lists_parameters_and_disabling(tmp_path):
    out = sbrdf("plugins")
    assert "synthetic" in out.stdout and "texels (list[int][2], default [64, 64]" in out.stdout
    out = sbrdf("-p", "no:fitters", "-p", "no:tables", "plugins", "--category", "fitter")
    assert "lm" not in out.stdout.split("fitter:")[1]


def test_info_on_missing_store(tmp_path):
    out = sbrdf("info", tmp_path)
    assert out.returncode == 2 and "no sbrdf artifacts" in out.stderr
