"""The Export node and plugin subcommands, exercised through a plugin registered like a third-party one."""

from __future__ import annotations

import json
import sys
import textwrap
import types
from pathlib import Path

import dask.array as da
import numpy as np
import pytest

from sbrdf_core.cli import main
from sbrdf_core.errors import PluginError
from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl
from sbrdf_core.registry import Registry
from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact


class GreyExporter:
    """Writes each texel's mean rho_d as a JSON list; the 'error' is the spread it threw away."""

    params = (Param("scale", "float", 1.0, "multiplies the exported value"),)

    def __init__(self, *, scale: float = 1.0):
        self.scale = scale

    def convert(self, material):
        rho = da.asarray(material.params["rho_d"])
        grey = rho.mean(axis=-1, keepdims=True) * self.scale
        return {"grey": grey, "error": (rho.max(axis=-1, keepdims=True) - rho.min(axis=-1, keepdims=True))}

    def write(self, directory, maps, material):
        Path(directory, "grey.json").write_text(json.dumps(maps["grey"][..., 0].tolist()))
        return {"files": ["grey.json"]}


class Hello:
    """`sbrdf hello NAME`."""

    @staticmethod
    def add_arguments(parser):
        parser.add_argument("who")

    def run(self, args) -> int:
        print(f"hello {args.who}")
        return 0


class NoWrite:
    def convert(self, material):
        return {}


@hookimpl
def sbrdf_exporters():
    return [PluginSpec("grey", f"{__name__}:GreyExporter", summary="mean rho_d as JSON"),
            PluginSpec("broken", f"{__name__}:NoWrite", summary="lacks write")]


@hookimpl
def sbrdf_commands():
    return [PluginSpec("hello", f"{__name__}:Hello", summary="say hello")]


PLUGIN = types.ModuleType("sbrdf_test_export_plugin")
PLUGIN.sbrdf_exporters = sbrdf_exporters
PLUGIN.sbrdf_commands = sbrdf_commands


def test_export_node_stores_maps_error_and_files(tmp_path):
    text = textwrap.dedent(f"""\
        name: export
        store: {tmp_path / 's'}
        nodes:
          a: {{kind: SampleModel, params: {{model: lambert, texels: [8, 4], poses: 20}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: a}}, params: {{model: lambert}}}}
          out: {{kind: Export, plugin: grey, in: {{material: fit}}, params: {{scale: 2.0}}}}
        """)
    run_graph(text, progress=False, registry=Registry(extra=[PLUGIN]))
    art = open_artifact(f"{tmp_path / 's'}/out")
    fit = open_artifact(f"{tmp_path / 's'}/fit")
    rho = fit.read("params/rho_d")
    assert art.kind == "Exported" and art.attrs["exporter"] == "grey" and art.attrs["files"] == ["grey.json"]
    np.testing.assert_allclose(art.read("maps/grey")[..., 0], 2.0 * rho.mean(-1), rtol=1e-6)
    np.testing.assert_allclose(json.loads((tmp_path / "s" / "out" / "grey.json").read_text()),
                               2.0 * rho.mean(-1), rtol=1e-6)
    assert art.attrs["error_max"] == pytest.approx(float((rho.max(-1) - rho.min(-1)).max()), rel=1e-5)


def test_an_exporter_without_write_is_refused_naming_the_member():
    reg = Registry(extra=[PLUGIN])
    with pytest.raises(PluginError, match="missing write"):
        reg.create("exporter", "broken", {})


def test_plugin_commands_become_subcommands(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "sbrdf_test_export_plugin", PLUGIN)
    assert main(["-p", "sbrdf_test_export_plugin", "hello", "world"]) == 0
    assert capsys.readouterr().out.strip() == "hello world"
