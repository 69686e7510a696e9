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
    out = sbrdf("-v", "run", "-q", path)
    assert out.stdout.count("cached") == 6
    assert "INFO sbrdf_core.runner: node 'fit': cached, reusing" in out.stderr, out.stderr  # -v: the run's log
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
    listed = out.stdout.split("fitter:")[1]
    assert "\n  lm " not in listed and "mcallister" not in listed and "lm-gl" in listed  # lm-gl is its own plugin


def test_info_on_missing_store(tmp_path):
    out = sbrdf("info", tmp_path)
    assert out.returncode == 2 and "no sbrdf artifacts" in out.stderr


def test_fit_table_describes_any_models_configuration():
    """The fit table names no model's parameters: it shows a fit's model configuration as declared."""
    from sbrdf_core.cli import describe_config

    assert describe_config({"lobes": 2, "transmission_lobes": 1}) == " lobes=2 transmission_lobes=1"
    assert describe_config({"anisotropic": True, "factors": "/some/store/path"}) == " anisotropic=true"
    assert describe_config({}) == ""
