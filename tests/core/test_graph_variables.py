"""Graph variables (``${name}``, ``variables:``) and overrides (``--set``): validated and tokenized as if written."""

from __future__ import annotations

import textwrap

import pytest

from sbrdf_core.cli import main
from sbrdf_core.errors import GraphError
from sbrdf_core.graph import load_graph, parse_value
from sbrdf_core.runner import Runner

GRAPH = """\
name: vars
store: {store}
variables:
  scan: ~
  seed: 3
  model: lambert
nodes:
  capture:
    kind: Capture
    plugin: synthetic
    params: {{texels: [8, 6], poses: 6, noise: 0.01, seed: "${{seed}}"}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}, params: {{tile: 8}}}}
  fit:
    kind: Fit
    plugin: lm
    in: {{samples: reflectance}}
    params: {{model: "${{model}}", iterations: 20}}
"""


def graph(write_graph, tmp_path, text=GRAPH, name="graph.yaml"):
    return write_graph(text.format(store=tmp_path / "runs" / "${scan}"), name)


def problems(excinfo) -> list[str]:
    return [str(p) for p in excinfo.value.problems]


def test_defaults_and_given_values_are_substituted_with_their_types(write_graph, registry, tmp_path):
    path = graph(write_graph, tmp_path)
    g = load_graph(path, registry, variables={"scan": "a"})
    assert g.store == str(tmp_path / "runs" / "a")  # inside a string: text
    assert g.nodes["capture"].params["seed"] == 3  # the whole value: the default, an int
    assert g.nodes["fit"].params["model"] == "lambert"
    assert g.variables == {"scan": "a", "seed": 3, "model": "lambert"}
    g = load_graph(path, registry, variables={"scan": "007", "seed": "11"})
    assert g.store.endswith("/runs/007")  # a text default or none: kept as text where interpolated
    assert g.nodes["capture"].params["seed"] == 11  # command-line text read as YAML where the default is a number


def test_a_required_variable_without_a_value_is_a_file_line_error(write_graph, registry, tmp_path):
    path = graph(write_graph, tmp_path)
    with pytest.raises(GraphError) as e:
        load_graph(path, registry)
    assert problems(e) == [f"{path}:4: variable 'scan' is required (declared without a default) and was given no "
                           f"value: pass --var scan=VALUE, or a 'scan' column in the --batch CSV"]


def test_an_undefined_variable_is_a_file_line_error(write_graph, registry, tmp_path):
    text = GRAPH.replace('noise: 0.01', 'noise: 0.01, model: "${{materal}}"')
    path = graph(write_graph, tmp_path, text)
    with pytest.raises(GraphError) as e:
        load_graph(path, registry, variables={"scan": "a"})
    assert any(p.startswith(f"{path}:11: undefined variable ${{materal}}: declare it under 'variables:'")
               for p in problems(e))
    # and in a graph that declares no variables at all
    plain = write_graph("name: p\nstore: s\nnodes:\n  c:\n    kind: Capture\n    plugin: synthetic\n"
                        "    params: {seed: '${seed}'}\n", "plain.yaml")
    with pytest.raises(GraphError) as e:
        load_graph(plain, registry)
    assert problems(e)[0].startswith(f"{plain}:7: undefined variable ${{seed}}")


def test_a_value_for_an_undeclared_variable_is_an_error(write_graph, registry, tmp_path):
    path = graph(write_graph, tmp_path)
    with pytest.raises(GraphError) as e:
        load_graph(path, registry, variables={"scan": "a", "sede": "4"})
    assert any("variable 'sede', but the graph declares no such variable; declared: scan, seed, model" in p
               for p in problems(e))


def test_substitution_inside_strings_nested_params_and_escapes(write_graph, registry, tmp_path):
    text = textwrap.dedent("""\
        name: "scan ${scan}"
        store: runs/${scan}-x
        description: "cost $${not} a ${scan}"
        variables: {scan: ~, lobes: 1, size: [8, 6]}
        nodes:
          capture: {kind: Capture, plugin: synthetic, params: {texels: "${size}", poses: 4,
                    model: lafortune, model_params: {lobes: "${lobes}"}}}
        """)
    g = load_graph(write_graph(text), registry, variables={"scan": "b7", "lobes": "2"})
    assert g.name == "scan b7" and g.store.endswith("/runs/b7-x")
    assert g.description == "cost ${not} a b7"
    p = g.nodes["capture"].params
    assert p["texels"] == [8, 6] and p["model_params"]["lobes"] == 2


def test_a_substituted_value_is_validated_by_the_plugin_param(write_graph, registry, tmp_path):
    path = graph(write_graph, tmp_path)
    with pytest.raises(GraphError) as e:
        load_graph(path, registry, variables={"scan": "a", "seed": "many"})
    [p] = problems(e)
    assert p.startswith(f"{path}:11: Capture plugin 'synthetic': parameter 'seed' should be int")
    assert p.endswith("(from ${seed} = 'many')")


def test_overrides_set_nested_paths_and_are_validated(write_graph, registry, tmp_path):
    path = graph(write_graph, tmp_path)
    g = load_graph(path, registry, variables={"scan": "a"},
                   overrides=["fit.params.iterations=7", "capture.poses=5", "capture.params.texels=[4, 4]",
                              "fit.params.model=lafortune", "fit.params.model_params.lobes=2"])
    assert g.nodes["capture"].params["poses"] == 5 and g.nodes["capture"].params["texels"] == [4, 4]
    assert g.nodes["fit"].params["iterations"] == 7 and g.nodes["fit"].params["model_params"]["lobes"] == 2
    assert g.overrides["capture.poses"] == 5
    with pytest.raises(GraphError) as e:
        load_graph(path, registry, variables={"scan": "a"},
                   overrides=["fitt.params.iterations=7", "capture.nonsense=1", "capture.poses=many",
                              "capture.texels.x=1", "capture"])
    ps = problems(e)
    assert any("--set fitt.params.iterations=7: the graph has no node 'fitt'; nodes: capture, register, "
               "reflectance, fit" in p for p in ps)
    assert any("unknown parameter 'nonsense' for Capture plugin 'synthetic'" in p
               and p.endswith("(set by --set capture.nonsense=1)") for p in ps)
    assert any(f"{path}:11: Capture plugin 'synthetic': parameter 'poses' should be int" in p
               and "(set by --set capture.poses=many)" in p for p in ps)
    assert any("capture.params.texels.x is not an index" in p for p in ps)
    assert any("--set capture: an override is PATH=VALUE" in p for p in ps)


def test_parse_value_reads_yaml_scalars_and_flow():
    assert parse_value("3") == 3 and parse_value("0.5") == 0.5 and parse_value("true") is True
    assert parse_value("[1, 2]") == [1, 2] and parse_value("{a: 1}") == {"a": 1}
    assert parse_value("/data/scan 1") == "/data/scan 1" and parse_value("") == ""


def test_tokens_change_only_for_affected_nodes(write_graph, registry, tmp_path):
    path = graph(write_graph, tmp_path)
    store = str(tmp_path / "one")
    first = Runner(registry).run(load_graph(path, registry, store=store, variables={"scan": "a"}))
    assert [r.status for r in first.nodes] == ["computed"] * 4
    again = Runner(registry).run(load_graph(path, registry, store=store, variables={"scan": "a"},
                                            overrides=["fit.params.iterations=9"]))
    assert [r.status for r in again.nodes] == ["cached"] * 3 + ["computed"]
    assert again["capture"].token == first["capture"].token and again["fit"].token != first["fit"].token
    seed = Runner(registry).run(load_graph(path, registry, store=store, variables={"scan": "a", "seed": "4"},
                                           overrides=["fit.params.iterations=9"]))
    assert all(r.status == "computed" for r in seed.nodes)


def test_a_variable_gives_the_same_tokens_as_the_value_written_in_the_file(write_graph, registry, tmp_path):
    with_var = load_graph(graph(write_graph, tmp_path), registry, store=str(tmp_path / "v"),
                          variables={"scan": "a", "seed": "5"})
    written = GRAPH.replace('"${{seed}}"', "5").replace('"${{model}}"', "lambert")
    plain = load_graph(write_graph(written.format(store=tmp_path / "w"), "written.yaml"), registry,
                       store=str(tmp_path / "w"), variables={"scan": "a"})
    a, b = Runner(registry).run(with_var, only=["capture"]), Runner(registry).run(plain, only=["capture"])
    assert a["capture"].token == b["capture"].token


def test_cli_var_and_set(write_graph, tmp_path, capsys):
    path = graph(write_graph, tmp_path)
    assert main(["run", "-q", str(path), "--var", "scan=c1", "--set", "fit.iterations=5", "--only", "capture"]) == 0
    assert (tmp_path / "runs" / "c1" / "capture").is_dir()
    assert main(["run", "-q", str(path), "--var", "scan=c1", "--set", "fiit.iterations=5"]) == 2
    assert "--set fiit.iterations=5: the graph has no node 'fiit'" in capsys.readouterr().err
    assert main(["run", "-q", str(path), "--var", "scan"]) == 2
    assert "--var scan: a variable is given as NAME=VALUE" in capsys.readouterr().err
