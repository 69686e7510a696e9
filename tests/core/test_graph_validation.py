"""Every validation error is reported before anything runs, with file, line and key."""

from __future__ import annotations

import textwrap

import pytest

from sbrdf_core.errors import GraphError
from sbrdf_core.graph import load_graph

from ..conftest import graph_yaml


def problems(write_graph, registry, text):
    path = write_graph(textwrap.dedent(text))
    with pytest.raises(GraphError) as exc:
        load_graph(path, registry)
    return exc.value, str(path)


def find(err, line, *needles):
    hits = [p for p in err.problems if p.line == line and all(n in p.message for n in needles)]
    assert hits, f"no problem on line {line} mentioning {needles}; got:\n{err}"
    return hits[0]


def test_valid_graph_loads_in_dependency_order(write_graph, registry, tmp_path):
    g = load_graph(write_graph(graph_yaml(tmp_path / "s")), registry)
    assert list(g.nodes) == ["capture", "register", "reflectance", "fit", "quantize", "render"]
    assert g.nodes["fit"].params["iterations"] == 200  # default filled in
    assert g.nodes["capture"].params["texels"] == [24, 20]


def test_message_names_file_and_line(write_graph, registry, tmp_path):
    err, path = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          a: {{kind: Captur, plugin: synthetic}}
        """)
    assert f"{path}:4:" in str(err)


def test_unknown_kind_lists_known(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          a: {{kind: Captur, plugin: synthetic}}
        """)
    p = find(err, 4, "unknown node kind 'Captur'")
    for kind in ("Capture", "Register", "Reflectance", "Fit", "Quantize", "Render"):
        assert kind in p.message


def test_unknown_plugin_lists_installed(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          cap:
            kind: Capture
            plugin: synthetik
        """)
    p = find(err, 6, "unknown capture plugin 'synthetik'")
    assert "synthetic" in p.message.split("installed:")[1]


def test_unknown_parameter_lists_accepted_with_types_and_defaults(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          cap:
            kind: Capture
            plugin: synthetic
            params:
              poses: 4
              texel: [8, 8]
        """)
    p = find(err, 9, "unknown parameter 'texel'")
    assert "texels (list[int][2], default [64, 64]" in p.message
    assert "poses (int, default 48" in p.message


def test_missing_required_parameter(write_graph, registry, tmp_path):
    from sbrdf_core.params import Param
    from sbrdf_core.plugin import PluginSpec, hookimpl
    from sbrdf_core.registry import Registry

    class Plug:
        @hookimpl
        def sbrdf_quantizers(self):
            return [PluginSpec("needs-bits", "sbrdf_quantizers.linear:LinearQuantizer", (Param("bits", "int", doc="bits per channel"),))]

    reg = Registry(extra=[Plug()])
    path = write_graph(graph_yaml(tmp_path / "s").replace("plugin: linear", "plugin: needs-bits, params: {}"))
    with pytest.raises(GraphError) as exc:
        load_graph(path, reg)
    find(exc.value, 8, "missing required parameter 'bits'", "bits (int, required)")


def test_ill_typed_and_out_of_range_parameters(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          cap:
            kind: Capture
            plugin: synthetic
            params:
              poses: many
              noise: -1.0
              texels: [8, 8, 8]
        """)
    find(err, 8, "'poses'", "should be int")
    find(err, 9, "'noise'", "outside")
    find(err, 10, "'texels'", "needs 2 items")


def test_nested_plugin_reference_and_its_parameters(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          cap:
            kind: Capture
            plugin: synthetic
            params: {{model: lamberd}}
        """)
    p = find(err, 7, "unknown brdf-model 'lamberd'")
    assert "lambert" in p.message


def test_missing_input(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          cap: {{kind: Capture, plugin: synthetic}}
          reg:
            kind: Register
            plugin: texel-aligned
        """)
    find(err, 5, "node 'reg': missing input 'capture' (CaptureSet)")


def test_input_from_unknown_node_and_unknown_port(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          cap: {{kind: Capture, plugin: synthetic}}
          reg:
            kind: Register
            plugin: texel-aligned
            in:
              capture: capp
              photos: cap
        """)
    find(err, 9, "unknown node 'capp'", "cap")
    find(err, 10, "has no input 'photos'", "capture (CaptureSet)")


def test_mistyped_input(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          cap: {{kind: Capture, plugin: synthetic}}
          fit:
            kind: Fit
            plugin: lm
            in:
              samples: cap
        """)
    find(err, 9, "input 'samples' needs SampledReflectance", "node 'cap' (Capture) produces CaptureSet")


def test_cycle(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          a: {{kind: Quantize, plugin: linear, in: {{params: c}}}}
          b: {{kind: Render, plugin: preview, in: {{material: a}}}}
          c: {{kind: Fit, plugin: lm, in: {{samples: b}}}}
        """)
    cycles = [p for p in err.problems if p.message.startswith("cycle:")]
    assert len(cycles) == 1 and cycles[0].line in (4, 5, 6), str(err)
    assert all(f"{n} ->" in cycles[0].message or f"-> {n}" in cycles[0].message for n in "abc")


def test_duplicate_node_names(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          cap: {{kind: Capture, plugin: synthetic}}
          cap: {{kind: Capture, plugin: synthetic, params: {{poses: 3}}}}
        """)
    find(err, 5, "duplicate node 'cap'", "line 4")


def test_store_that_cannot_be_opened(write_graph, registry, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {blocker}/runs
        nodes:
          cap: {{kind: Capture, plugin: synthetic}}
        """)
    find(err, 2, "store", "cannot be opened", "not a directory")
    err, _ = problems(write_graph, registry, """\
        name: g
        store: nosuchproto://bucket/x
        nodes:
          cap: {kind: Capture, plugin: synthetic}
        """)
    find(err, 2, "store", "cannot be opened")


def test_unknown_keys_and_yaml_syntax(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        stroe: x
        nodes:
          cap: {{kind: Capture, plugin: synthetic, parms: {{}}}}
        """)
    find(err, 3, "unknown top-level key 'stroe'")
    find(err, 5, "unknown key 'parms'", "params")
    err, _ = problems(write_graph, registry, "name: g\nnodes:\n  a: {kind: [\n")
    assert err.problems[0].line is not None and "YAML syntax error" in err.problems[0].message


def test_all_problems_reported_at_once(write_graph, registry, tmp_path):
    err, _ = problems(write_graph, registry, f"""\
        name: g
        store: {tmp_path}/s
        nodes:
          a: {{kind: Capture, plugin: nope}}
          b: {{kind: Nope}}
          c: {{kind: Fit, plugin: lm, in: {{samples: zz}}, params: {{bogus: 1}}}}
        """)
    assert {p.line for p in err.problems} >= {4, 5, 6}
    assert len(err.problems) >= 4


def test_graph_yaml_is_never_executed(write_graph, registry, tmp_path):
    # Python tags are refused by the safe loader instead of running code.
    err, _ = problems(write_graph, registry, f"""\
        name: !!python/object/apply:os.system ["echo pwned > {tmp_path}/pwned"]
        store: {tmp_path}/s
        nodes:
          cap: {{kind: Capture, plugin: synthetic}}
        """)
    assert not (tmp_path / "pwned").exists()
    assert err.problems


def test_exponent_floats_without_a_dot_are_numbers():
    """PyYAML (YAML 1.1) reads ``1e-3`` as a string; a float parameter takes it as the number users mean."""
    from sbrdf_core.params import Param, ParameterError

    assert Param("noise", "float", 0.0).check("1e-3") == 1e-3
    assert Param("xs", "list", [0.0], item="float").check(["-2.5E+4", 1]) == [-25000.0, 1.0]
    with pytest.raises(ParameterError, match="should be float"):
        Param("noise", "float", 0.0).check("1e-3x")
    with pytest.raises(ParameterError, match="should be str"):
        Param("name", "str", "").check(1e-3)
