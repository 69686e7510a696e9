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
    assert "\n  lm " not in listed and "mcallister" not in listed and "lm-gl" not in listed
    assert "\n  svd " in listed  # a fitter of another plugin (separable) stays


def test_info_on_missing_store(tmp_path):
    out = sbrdf("info", tmp_path)
    assert out.returncode == 2 and "no sbrdf artifacts" in out.stderr


def test_fit_table_describes_any_models_configuration():
    """The fit table names no model's parameters: it shows a fit's model configuration as declared."""
    from sbrdf_core.cli import describe_config

    assert describe_config({"lobes": 2, "transmission_lobes": 1}) == " lobes=2 transmission_lobes=1"
    assert describe_config({"anisotropic": True, "factors": "/some/store/path"}) == " anisotropic=true"
    assert describe_config({}) == ""


def test_fit_table_stays_aligned_with_a_long_model_description():
    """A model whose configuration is long widens its column up to a cap, then is cut with ``…``: every row's
    numeric columns end where the header's do."""
    from types import SimpleNamespace

    from sbrdf_core.cli import fit_table

    summary = {"fit_time_s": 1.5, "rms_mean": 0.01, "rms_max": 0.2, "rms_holdout_mean": 0.02, "texels_flagged_any": 3}
    config = {f"parameter_{k}": k for k in range(12)}  # far wider than any cap
    fits = [(f"/s/{name}", SimpleNamespace(attrs={"model": model, "model_config": cfg, "fitter": "lm",
                                                 "texels": [4, 4], "summary": summary}))
            for name, model, cfg in [("fit", "lambert", {}), ("fit-long", "lafortune", config),
                                     ("a-" + "very-" * 12 + "long-node-name", "ward", {"anisotropic": True})]]
    lines = fit_table(fits).splitlines()
    assert len(lines) == 2 + len(fits)
    assert len({len(line) for line in lines}) == 1, lines  # aligned: every row as wide as the header
    head = lines[0]
    for col in ("texels", "fit_s", "avg_rms", "max_rms", "held_out", "flagged"):
        end = head.index(col) + len(col)
        assert all(line[end - 1] != " " and (end == len(line) or line[end] == " ") for line in lines[2:]), col
    assert "…" in lines[3] and lines[3].split()[1:3] == ["lm", "lafortune"]
    assert "lafortune parameter_0=0 parameter_1=1" in lines[3]
    assert lines[2].split()[:3] == ["fit", "lm", "lambert"] and lines[2].split()[3:] == ["16", "1.5", "0.01", "0.2",
                                                                                         "0.02", "3"]
