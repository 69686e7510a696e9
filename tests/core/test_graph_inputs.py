"""Hostile and damaged graph and scene files: every one is a validation error at file:line, never a traceback or a hang.

Issue 21, "Graph files": alias bombs, deep nesting, recursive anchors,
undecodable files, non-scalar keys and object tags in the YAML; NaN and
infinity in parameters; scene-effect options and the files a scene names
(meshes, environment maps, measured tables) checked before anything runs;
and graphs too big for the disk or the memory refused up front.
"""

from __future__ import annotations

import os
import shutil
import textwrap
import time
from pathlib import Path

import pytest

from sbrdf_core.errors import GraphError
from sbrdf_core.graph import load_graph
from sbrdf_core.params import Param
from sbrdf_lib.scene import SceneError, load_scene

ROOT = Path(__file__).resolve().parents[2]
SKY = ROOT / "scenes" / "envmap_sky.exr"


def header(tmp_path) -> str:
    return f"name: g\nstore: {tmp_path / 'store'}\n"


def pipeline(tmp_path, capture: str = "{texels: [8, 8], poses: 8}", extra: str = "", render: str = "") -> str:
    return header(tmp_path) + extra + textwrap.dedent(f"""\
        nodes:
          capture: {{kind: Capture, plugin: synthetic, params: {capture}}}
          register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
          reflectance: {{kind: Reflectance, in: {{stack: register}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lambert}}}}
        """) + render


def invalid(path, registry=None) -> GraphError:
    with pytest.raises(GraphError) as exc:
        load_graph(path, registry)
    return exc.value


def only(err: GraphError, line: int | None, *needles: str):
    hits = [p for p in err.problems if (line is None or p.line == line) and all(n in p.message for n in needles)]
    assert hits, f"no problem on line {line} mentioning {needles}; got:\n{err}"
    return hits[0]


# -- the YAML itself ----------------------------------------------------------------------------------------------


def bomb(levels: int) -> str:
    """An alias bomb under ``description:``: 10**levels strings from a few hundred bytes."""
    lines = ["  l0: &l0 [x, x, x, x, x, x, x, x, x, x]"]
    for i in range(1, levels):
        lines.append(f"  l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 10) + "]")
    return "description:\n" + "\n".join(lines) + "\n"


def test_alias_bomb_is_refused_quickly_with_its_line(write_graph, registry, tmp_path):
    # 10**6 values: the old loader expanded them all (10**9 hung); the limit is 10**5
    path = write_graph(pipeline(tmp_path, extra=bomb(6)))
    start = time.perf_counter()
    err = invalid(path, registry)
    assert time.perf_counter() - start < 10
    p = only(err, None, "aliases expand to more than")
    assert 3 <= p.line <= 9 and str(path) in str(err)


def test_modest_aliases_and_merges_still_work(write_graph, registry, tmp_path):
    text = pipeline(tmp_path, capture="{<<: *cap, poses: 8}", extra="description: &cap {texels: [8, 8]}\n")
    g = load_graph(write_graph(text), registry)
    assert g.nodes["capture"].params["texels"] == [8, 8] and g.nodes["capture"].params["poses"] == 8


@pytest.mark.parametrize("opening, closing", [("[", "]"), ("{a: ", "}")])
def test_deep_nesting_is_an_error_not_a_recursion_error(write_graph, registry, tmp_path, opening, closing):
    text = header(tmp_path) + "nodes:\n  x: " + opening * 3000 + "1" + closing * 3000 + "\n"
    err = invalid(write_graph(text), registry)
    only(err, 4, "nesting deeper than")


def test_aliases_cannot_nest_deeper_than_anchors_may(write_graph, registry, tmp_path):
    deep = lambda body: "[" * 40 + body + "]" * 40  # noqa: E731
    extra = f"description:\n  a: &a {deep('1')}\n  b: &b {deep('*a')}\n  c: {deep('*b')}\n"
    only(invalid(write_graph(pipeline(tmp_path, extra=extra)), registry), None, "nesting deeper than 64", "aliases")


def test_recursive_anchor_is_an_error(write_graph, registry, tmp_path):
    err = invalid(write_graph(header(tmp_path) + "nodes: &n\n  x: {kind: Capture, in: *n}\n"), registry)
    only(err, 3, "recursive alias")  # the anchor's line


@pytest.mark.parametrize("key, what", [("? [a, b]\n  : 1", "a list"), ("{a: 1}: 1", "a mapping"),
                                       ("? {a: 1}\n  : 1", "a mapping")])
def test_list_or_mapping_as_key(write_graph, registry, tmp_path, key, what):
    err = invalid(write_graph(header(tmp_path) + f"nodes:\n  {key}\n"), registry)
    only(err, 4, f"{what} cannot be a mapping key")


@pytest.mark.parametrize("value", ["!!python/object/apply:os.system [echo hi]", "!!python/name:os.system",
                                   "!!python/object:collections.OrderedDict {}", "!custom x", "!!set {a, b}"])
def test_disallowed_tags_are_named(write_graph, registry, tmp_path, value):
    tag = value.split()[0]
    err = invalid(write_graph(f"name: {value}\nstore: {tmp_path / 's'}\nnodes: {{}}\n"), registry)
    p = only(err, 1, f"tag {tag} is not allowed")
    assert "needs a 'name'" not in str(err), p


def test_latin1_file_names_the_byte_and_line(tmp_path, registry):
    path = tmp_path / "g.yaml"
    path.write_bytes(pipeline(tmp_path).replace("name: g", "name: g\ndescription: caf\u00e9").encode("latin-1"))
    err = invalid(path, registry)
    p = only(err, 2, "not UTF-8", "0xe9", "line 2, column 17")
    assert str(p).startswith(f"{path}:2:")


def test_binary_file(tmp_path, registry):
    path = tmp_path / "g.yaml"
    path.write_bytes(bytes(range(256)) * 8)
    only(invalid(path, registry), 1, "NUL byte", "binary")


def test_utf8_without_nul_but_with_control_characters(tmp_path, registry):
    path = tmp_path / "g.yaml"
    path.write_bytes(b"name: g\nstore: s\x07\nnodes: {}\n")
    only(invalid(path, registry), 2, "#x0007", "not allowed")


def test_utf16_with_a_bom_is_read_and_without_one_is_an_error(tmp_path, registry):
    text = pipeline(tmp_path).replace("name: g", "name: g\ndescription: caf\u00e9")
    with_bom = tmp_path / "bom.yaml"
    with_bom.write_bytes(text.encode("utf-16"))
    g = load_graph(with_bom, registry)
    assert g.description == "caf\u00e9" and list(g.nodes) == ["capture", "register", "reflectance", "fit"]
    no_bom = tmp_path / "nobom.yaml"
    no_bom.write_bytes(text.encode("utf-16-le"))
    only(invalid(no_bom, registry), 1, "NUL byte", "UTF-16/32 text without a byte-order mark")


SCENE = """\
camera: {position: [0, -3, 2], look_at: [0, 0, 0], resolution: [32, 24]}
materials:
  sample: {artifact: input}
  paint: {model: phong, params: {rho_d: [0.2, 0.1, 0.1], rho_s: [0.5, 0.5, 0.5], exponent: 40}}
objects:
  - {shape: plane, size: [2, 2], material: sample}
#more
lights:
  - {type: point, position: [2, -2, 3], intensity: 10}
"""


@pytest.mark.parametrize("bad, needle", [
    (lambda p: p.write_bytes(SCENE.replace("#more", "# caf\u00e9").encode("latin-1")), "not UTF-8"),
    (lambda p: p.write_text(SCENE.replace("intensity: 10", "intensity: !!python/object/apply:os.getcwd []")),
     "tag !!python/object/apply:os.getcwd is not allowed"),
    (lambda p: p.write_text(SCENE + "background: &b [*b]\n"), "recursive alias"),
    (lambda p: p.write_text(SCENE + "shadows: " + "[" * 2000 + "]" * 2000 + "\n"), "nesting deeper"),
    (lambda p: p.write_text(SCENE + "? [a]\n: 1\n"), "a list cannot be a mapping key"),
])
def test_scene_files_get_the_same_treatment(tmp_path, bad, needle):
    path = tmp_path / "scene.yaml"
    bad(path)
    with pytest.raises(SceneError) as exc:
        load_scene(str(path))
    assert needle in str(exc.value) and f"{path}:" in str(exc.value)


def test_scene_alias_bomb(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text(SCENE + "effects:\n  x:\n" + "\n".join("  " + ln for ln in bomb(6).splitlines()[1:]) + "\n")
    start = time.perf_counter()
    with pytest.raises(SceneError, match="aliases expand to more than"):
        load_scene(str(path))
    assert time.perf_counter() - start < 10


# -- non-finite numbers --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("value", [".nan", ".NaN", ".inf", "-.inf", "1e400", "-1e400"])
def test_nan_and_infinity_are_refused_by_parameter_checks(write_graph, registry, tmp_path, value):
    path = write_graph(pipeline(tmp_path, capture=f"{{texels: [8, 8], poses: 8, noise: {value}}}"))
    p = only(invalid(path, registry), 4, "parameter 'noise' is not a finite number")
    assert "NaN and infinity are not accepted" in p.message


def test_non_finite_inside_lists_and_mappings(write_graph, registry, tmp_path):
    path = write_graph(pipeline(tmp_path, capture="{texels: [8, 8], poses: 8, size_mm: [100, .nan]}"))
    only(invalid(path, registry), 4, "parameter 'size_mm' is not a finite number (at size_mm[1])")
    with pytest.raises(Exception, match=r"not a finite number \(at x.a.b\[0\]\)"):
        Param("x", "dict").check({"a": {"b": [float("nan")]}})
    with pytest.raises(Exception, match="not a finite number"):
        Param("x", "any").check(float("-inf"))


def test_a_parameter_may_declare_that_it_accepts_them():
    assert Param("x", "float", bounds=(0, None), nonfinite=True).check(float("inf")) == float("inf")
    assert Param("x", "list", item="float", nonfinite=True).check([1.0, float("nan")])[1] != 0
    with pytest.raises(Exception, match="not a finite number"):
        Param("x", "float", bounds=(0, None)).check(float("inf"))


def test_non_finite_scene_values(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text(SCENE.replace("position: [0, -3, 2]", "position: [0, -3, 1e400]"))
    with pytest.raises(SceneError, match=r"scene.yaml:1: camera: parameter 'position' is not a finite number"):
        load_scene(str(path))


# -- scenes: effects and referenced files checked at validation ---------------------------------------------------


def render_graph(tmp_path, scene_text: str) -> Path:
    (tmp_path / "scene.yaml").write_text(scene_text)
    path = tmp_path / "graph.yaml"
    path.write_text(pipeline(tmp_path, render="  render: {kind: Render, plugin: cpu, in: {material: fit}, "
                                              "params: {scene: scene.yaml}}\n"))
    return path


@pytest.mark.parametrize("scene, needle", [
    (SCENE + "environment: {file: missing.exr}\n", "environment: file"),
    (SCENE + "environment: {file: garbage.exr}\n", "cannot read the environment map"),
    (SCENE + "environment: {file: sky.exr, options: {size: 3}}\n", "power of two"),
    (SCENE + "environment: {file: sky.exr, options: {method: magic}}\n", "parameter 'method' is 'magic'"),
    (SCENE + "environment: {file: sky.exr, options: {samples: .nan}}\n", "not a finite number"),
    (SCENE + "environment: {file: sky.exr, intensity: -1}\n", "parameter 'intensity' = -1.0 is outside"),
    (SCENE + "effects: {no-such-effect: {}}\n", "no installed scene effect provides ['no-such-effect']"),
    (SCENE.replace("#more", "  - {shape: mesh, file: bad.obj, material: sample}"), "malformed OBJ line 'f 1 2 x'"),
    (SCENE.replace("#more", "  - {shape: mesh, file: latin.obj, material: sample}"), "not a UTF-8 OBJ file"),
    (SCENE.replace("#more", "  - {shape: mesh, file: empty.obj, material: sample}"), "the mesh has no faces"),
    (SCENE.replace("#more", "  - {shape: sphere, material: paint}").replace("exponent: 40", "exponent: 40, shine: 1"),
     "unknown parameter(s) ['shine'] for model 'phong'"),
    (SCENE.replace("#more", "  - {shape: sphere, material: paint}").replace("model: phong", "model: fong"),
     "unknown brdf-model plugin 'fong'"),
    (SCENE.replace("size: [2, 2], material: sample}", "size: [2, 2], material: sample, reflector: true}")
     .replace("#more", "  - {shape: plane, material: sample, reflector: true}"), "one reflector: true plane is supported"),
])
def test_scene_problems_are_found_before_anything_runs(tmp_path, registry, scene, needle):
    shutil.copy(SKY, tmp_path / "sky.exr")
    (tmp_path / "garbage.exr").write_bytes(b"this is not an OpenEXR file")
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n")
    (tmp_path / "latin.obj").write_bytes("# caf\u00e9\nv 0 0 0\n".encode("latin-1"))
    (tmp_path / "empty.obj").write_text("v 0 0 0\n")
    err = invalid(render_graph(tmp_path, scene), registry)
    p = only(err, 8, needle)
    assert "Render plugin 'cpu'" in p.message and "scene.yaml" in p.message
    assert not (tmp_path / "store").exists()  # nothing ran


def test_scene_checks_use_the_validating_registry(tmp_path):
    from sbrdf_core.registry import Registry

    shutil.copy(SKY, tmp_path / "sky.exr")
    path = render_graph(tmp_path, SCENE + "environment: {file: sky.exr}\n")
    load_graph(path, Registry())
    err = invalid(path, Registry(disabled=["envmap"]))
    only(err, 8, "unknown scene key 'environment'")  # the key comes with the envmap plugin (sbrdf_scene_keys)


def test_a_good_scene_with_environment_and_mesh_validates(tmp_path, registry):
    shutil.copy(SKY, tmp_path / "sky.exr")
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    scene = SCENE.replace("#more", "  - {shape: mesh, file: tri.obj, material: paint}") + "environment: {file: sky.exr}\n"
    g = load_graph(render_graph(tmp_path, scene), registry)
    assert "render" in g.nodes


def test_measured_table_file_is_read_at_validation(tmp_path, registry):
    table = tmp_path / "t.csv"
    table.write_text("theta_i,phi_i,theta_o,phi_o,p\n0,0,10,0,0.1\n0,0,20,0,abc\n")
    path = tmp_path / "graph.yaml"
    path.write_text(header(tmp_path) + textwrap.dedent("""\
        nodes:
          table: {kind: MeasuredTable, params: {path: t.csv}}
          fit: {kind: Fit, plugin: lm, in: {samples: table}, params: {model: lambert}}
        """))
    only(invalid(path, registry), 4, "t.csv:3: p is not a number: 'abc'")
    table.write_bytes("# caf\u00e9\ntheta_i,phi_i,theta_o,phi_o,p\n".encode("latin-1"))
    only(invalid(path, registry), 4, "not UTF-8")


# -- files a scene or node names: regular files only, never a blocking open ------------------------------------


class _Hung(Exception):
    pass


def within(seconds: int, call):
    """``call()``, failing the test if it blocks longer than ``seconds`` (an open of a FIFO nobody writes)."""
    import signal

    def hung(*_):
        raise _Hung(f"blocked for more than {seconds} s")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(seconds)
    try:
        return call()
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize("where", ["mesh", "environment", "table", "merl"])
@pytest.mark.parametrize("special", ["fifo", "/dev/zero"])
def test_a_fifo_or_device_named_by_a_scene_or_node_is_refused_naming_it(tmp_path, registry, where, special):
    if special == "fifo":
        target = tmp_path / {"mesh": "m.obj", "environment": "sky.exr", "table": "t.csv", "merl": "m.binary"}[where]
        os.mkfifo(target)  # nobody writes: opening it for reading would wait forever
        kind = "a FIFO (named pipe), not a regular file"
    else:
        if not os.path.exists(special):
            pytest.skip(f"no {special}")
        target, kind = Path(special), "a character device, not a regular file"
    if where in ("mesh", "environment"):
        scene = (SCENE.replace("#more", f"  - {{shape: mesh, file: {target}, material: paint}}") if where == "mesh"
                 else SCENE + f"environment: {{file: {target}}}\n")
        path, line = render_graph(tmp_path, scene), 8
    else:
        node = (f"{{kind: MeasuredTable, params: {{path: {target}}}}}" if where == "table"
                else f"{{kind: MeasuredBRDF, params: {{path: {target}, format: merl}}}}")
        path, line = tmp_path / "graph.yaml", 4
        path.write_text(header(tmp_path) + f"nodes:\n  table: {node}\n"
                        "  fit: {kind: Fit, plugin: lm, in: {samples: table}, params: {model: lambert}}\n")
    err = within(20, lambda: invalid(path, registry))
    p = only(err, line, str(target))
    # /dev/zero has no mesh suffix: refused for its format before it is opened
    assert kind in p.message or (where == "mesh" and "unsupported format" in p.message), p.message


def test_a_mesh_over_the_data_limit_is_refused(tmp_path, registry, monkeypatch):
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n" + "# padding\n" * 100)
    monkeypatch.setenv("SBRDF_MAX_INPUT_BYTES", "100")
    scene = SCENE.replace("#more", "  - {shape: mesh, file: tri.obj, material: paint}")
    only(invalid(render_graph(tmp_path, scene), registry), 8, "tri.obj", "more than the 100-byte limit",
         "SBRDF_MAX_INPUT_BYTES")


# -- sizes: output bytes and peak memory estimated up front -----------------------------------------------------


def test_a_graph_too_big_for_the_disk_is_refused_naming_the_node(write_graph, registry, tmp_path):
    path = write_graph(pipeline(tmp_path, capture="{texels: [16384, 16384], poses: 100000}"))
    err = invalid(path, registry)
    p = only(err, 4, "node 'capture' would write about", "TB", "free on the store's filesystem")
    assert "100000 poses × 16384×16384" in p.message and "max_bytes" in p.message
    only(err, 5, "node 'register' would write")
    only(err, 6, "node 'reflectance' would write")


def test_max_bytes_from_the_graph_and_the_environment(write_graph, registry, tmp_path, monkeypatch):
    small = "{texels: [64, 64], poses: 64}"  # 3.4 MB a node, uncompressed
    load_graph(write_graph(pipeline(tmp_path, capture=small)), registry)
    err = invalid(write_graph(pipeline(tmp_path, capture=small, extra="limits: {max_bytes: 1 MB}\n")), registry)
    only(err, 5, "node 'capture' would write about 3.4 MB", "the limit max_bytes = 1.0 MB")
    err = invalid(write_graph(pipeline(tmp_path, capture=small, extra="limits: {max_bytes: 5 MB}\n")), registry)
    only(err, None, "the graph's nodes would write about", "together", "5.0 MB")
    monkeypatch.setenv("SBRDF_MAX_BYTES", "2MiB")
    only(invalid(write_graph(pipeline(tmp_path, capture=small)), registry), 4, "node 'capture'", "2.1 MB")
    # the graph's limit wins over the environment
    load_graph(write_graph(pipeline(tmp_path, capture=small, extra="limits: {max_bytes: 1 GB}\n")), registry)


def test_max_memory_names_the_node(write_graph, registry, tmp_path):
    text = pipeline(tmp_path, capture="{texels: [1024, 1024], poses: 16}", extra="limits: {max_memory: 20 MB}\n")
    err = invalid(write_graph(text), registry)
    p = only(err, None, "node 'capture' would hold about", "in one task", "max_memory = 20.0 MB")
    assert p.line == 5


@pytest.mark.parametrize("limits, needle", [("{max_bytes: lots}", "not a size: 'lots'"),
                                            ("{max_bytes: -5}", "not a positive size"),
                                            ("{max_disk: 1 GB}", "unknown limit 'max_disk'"),
                                            ("[1 GB]", "'limits' must be a mapping")])
def test_bad_limits(write_graph, registry, tmp_path, limits, needle):
    only(invalid(write_graph(pipeline(tmp_path, extra=f"limits: {limits}\n")), registry), 3, needle)


def test_nodes_already_in_the_store_do_not_count_against_the_disk(write_graph, registry, tmp_path):
    # capture, register and reflectance: 3.4 MB each, 10.2 MB together
    text = pipeline(tmp_path, capture="{texels: [64, 64], poses: 64}", extra="limits: {max_bytes: 8 MB}\n")
    only(invalid(write_graph(text), registry), None, "the graph's nodes would write about", "together")
    (tmp_path / "store" / "capture").mkdir(parents=True)
    (tmp_path / "store" / "capture" / "zarr.json").write_text("{}")
    load_graph(write_graph(text), registry)  # the capture is on the disk already: 6.8 MB to write
