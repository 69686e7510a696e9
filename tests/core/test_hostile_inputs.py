"""Hostile values and files through the real ``sbrdf`` command: clear errors at file:line, never a traceback or a hang.

Nested model parameters (``SampleModel``'s ``params:``) checked against the
model's declarations; integer literals Python will not convert or a float
cannot hold; stores that cannot be written; graphs and scenes that are
devices, FIFOs or too large; and the command line's rule that an unexpected
exception is one line (the traceback with ``-v``), disk full said plainly.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from sbrdf_core.cli import main

ROOT = Path(__file__).resolve().parents[2]
SBRDF = [sys.executable, "-m", "sbrdf_core.cli"]


def sbrdf(*args: str, env: dict | None = None, timeout: float = 120, cwd=None) -> subprocess.CompletedProcess:
    """``sbrdf ARGS`` in a subprocess: a hang is a failure (the timeout), not a stuck test run."""
    full_env = {**os.environ, **(env or {})}
    full_env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), full_env.get("PYTHONPATH", "")]))
    return subprocess.run(SBRDF + list(args), capture_output=True, text=True, timeout=timeout, env=full_env, cwd=cwd)


def no_traceback(r: subprocess.CompletedProcess) -> None:
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, r.stderr[-3000:]


def sample_graph(tmp_path, params: str, extra: str = "", name: str = "graph.yaml") -> Path:
    """A SampleModel graph; ``params`` (YAML lines) go under the node's ``params:``, from line 10."""
    path = tmp_path / name
    lines = ["name: g", f"store: {tmp_path / 'store'}", "nodes:", "  samples:", "    kind: SampleModel",
             "    params:", "      model: lafortune", "      texels: [4, 4]", "      poses: 8"]
    path.write_text("\n".join(lines + ["      " + line for line in params.splitlines()]) + "\n" + extra)
    return path


def validate(capsys, path: Path) -> tuple[int, str]:
    rc = main(["validate", str(path)])
    out = capsys.readouterr()
    return rc, out.out + out.err


# -- SampleModel's params: the model's own declarations -------------------------------------------------------


@pytest.mark.parametrize("value, line_has", [
    ("params: {bogus: 0.1}", "has no parameter 'bogus'; its parameters: rho_d, rho_s_1"),
    ("params: {rho_d: 1.0e+300}", "params.rho_d = 1e+300 is outside the parameter's valid range [0, 100]"),
    ("params: {rho_d: .nan}", "is not a finite number (at params.rho_d)"),
    ("params: {rho_d: abc}", "params.rho_d should be a number or a list of 3 numbers (one per channel), got str 'abc'"),
    ("params: {rho_d: 2020-01-01}", "params.rho_d should be a number or a list of 3 numbers (one per channel), got date"),
    ("params: {rho_d: [0.1, 0.2]}", "params.rho_d has 2 values"),
    ("params: {rho_d: true}", "got bool True"),
    ("params: {exponent_1: 1.0e+9}", "params.exponent_1 = 1e+09 is outside"),
])
def test_sample_model_params_are_checked_against_the_models_declarations(tmp_path, capsys, value, line_has):
    path = sample_graph(tmp_path, value)
    rc, out = validate(capsys, path)
    assert rc == 2, out
    assert f"{path}:10: SampleModel node: " in out and line_has in out, out


def test_sample_model_params_follow_the_model_configuration(tmp_path, capsys):
    # a second lobe's parameters exist only with lobes: 2
    path = sample_graph(tmp_path, "model_params: {lobes: 2}\nparams: {rho_s_2: [0.1, 0.1, 0.1], rho_d: 0.1}")
    rc, out = validate(capsys, path)
    assert rc == 0, out
    path = sample_graph(tmp_path, "params: {rho_s_2: 0.1}")
    rc, out = validate(capsys, path)
    assert rc == 2 and "has no parameter 'rho_s_2'" in out


def test_valid_sample_model_params_still_run(tmp_path, capsys):
    path = sample_graph(tmp_path, "params: {rho_d: [0.1, 0.2, 0.3], exponent_1: 1.0e+1, c_z_1: 1}")
    assert main(["run", "-q", str(path)]) == 0, capsys.readouterr()


# -- numbers the loader or a float cannot hold ----------------------------------------------------------------


def test_an_integer_of_5000_digits_is_a_line_error(tmp_path):
    path = sample_graph(tmp_path, f"seed: {'9' * 5000}")
    r = sbrdf("validate", str(path))
    no_traceback(r)
    assert r.returncode == 2 and f"{path}:10: value '9999" in r.stderr and "5000 characters" in r.stderr
    assert "Exceeds the limit (4300 digits)" in r.stderr and "set_int_max_str_digits" not in r.stderr


def test_an_integer_too_large_for_a_float_parameter(tmp_path, capsys):
    path = sample_graph(tmp_path, f"noise: {'9' * 400}")
    rc, out = validate(capsys, path)
    assert rc == 2 and f"{path}:10: SampleModel node: parameter 'noise' = an integer of 400 digits is too " \
                       "large for a float" in out, out


def test_an_integer_beyond_64_bits_is_refused(tmp_path, capsys):
    path = sample_graph(tmp_path, f"seed: {2**64}")
    rc, out = validate(capsys, path)
    assert rc == 2 and f"{path}:10:" in out and "does not fit in a 64-bit integer" in out, out


# -- stores ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("store", ["http://127.0.0.1:1/x", "https://example.invalid/s", "zip://a.zip"])
def test_a_read_only_store_is_refused_at_validation(tmp_path, store):
    path = sample_graph(tmp_path, "seed: 1")
    path.write_text(path.read_text().replace(f"store: {tmp_path / 'store'}", f"store: {store}"))
    for command in ("validate", "run"):
        r = sbrdf(command, str(path), timeout=60)
        no_traceback(r)
        assert r.returncode == 2 and f"{path}:2: store '{store}' cannot be written" in r.stderr, r.stderr


# -- files a graph names: regular files only, bounded ---------------------------------------------------------


def render_graph(tmp_path, scene: str) -> Path:
    path = tmp_path / "render.yaml"
    path.write_text(textwrap.dedent(f"""\
        name: r
        store: {tmp_path / 'store'}
        nodes:
          samples: {{kind: SampleModel, params: {{model: lambert, texels: [4, 4], poses: 8}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lambert}}}}
          render: {{kind: Render, plugin: cpu, in: {{material: fit}}, params: {{scene: {scene}}}}}
        """))
    return path


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_a_device_as_graph_or_scene_is_refused_at_once(tmp_path, device):
    if not os.path.exists(device):
        pytest.skip(f"no {device}")
    r = sbrdf("validate", device, timeout=30)
    no_traceback(r)
    assert r.returncode == 2 and f"{device}: cannot read graph file: it is a character device, not a regular file" \
        in r.stderr, r.stderr
    path = render_graph(tmp_path, device)
    for command in ("validate", "run"):
        r = sbrdf(command, str(path), timeout=60)
        no_traceback(r)
        assert r.returncode == 2 and f"{path}:6:" in r.stderr and "a character device, not a regular file" in r.stderr, \
            r.stderr
    assert not (tmp_path / "store" / "render").exists()


def test_a_fifo_as_graph_or_scene_does_not_block(tmp_path):
    fifo = tmp_path / "scene.yaml"
    os.mkfifo(fifo)  # nobody writes: an open for reading would wait forever
    r = sbrdf("validate", str(fifo), timeout=30)
    no_traceback(r)
    assert r.returncode == 2 and "a FIFO (named pipe), not a regular file" in r.stderr
    r = sbrdf("validate", str(render_graph(tmp_path, str(fifo))), timeout=60)
    no_traceback(r)
    assert r.returncode == 2 and ":6:" in r.stderr and "a FIFO (named pipe)" in r.stderr, r.stderr


def test_a_directory_as_scene_is_named(tmp_path, capsys):
    (tmp_path / "d").mkdir()
    rc, out = validate(capsys, render_graph(tmp_path, str(tmp_path / "d")))
    assert rc == 2 and "a directory, not a regular file" in out, out


def test_a_graph_over_the_size_limit_is_refused_naming_the_variable(tmp_path):
    path = sample_graph(tmp_path, "seed: 1", extra="# " + "x" * 4000 + "\n")
    r = sbrdf("validate", str(path), env={"SBRDF_MAX_TEXT_BYTES": "1000"})
    no_traceback(r)
    assert r.returncode == 2 and "bytes, more than the 1000-byte limit for text inputs (set SBRDF_MAX_TEXT_BYTES" \
        in r.stderr, r.stderr
    assert sbrdf("validate", str(path)).returncode == 0  # the default limit (64 MiB) reads it


# -- the command line: one line, never a traceback ------------------------------------------------------------

PLUGIN = '''
import os
from sbrdf_core.artifacts import SampledReflectance
from sbrdf_core.nodes.base import NodeKind
from sbrdf_core.params import Param
from sbrdf_core.plugin import hookimpl


class Broken(NodeKind):
    name = "Broken"
    doc = "a node kind whose own check has a bug"
    output = SampledReflectance
    params = (Param("x", "int", 0, "anything"),)

    @staticmethod
    def check_params(params):
        return {}["no such key"]


class DiskFull(NodeKind):
    name = "DiskFull"
    doc = "a node kind that writes to a full disk while it builds"
    output = SampledReflectance
    params = (Param("path", "str", "/dev/full", "where it writes"),)

    @classmethod
    def build(cls, ctx):
        with open(ctx.params["path"], "w") as f:
            f.write("x" * 65536)
        raise AssertionError("the write above fails")


@hookimpl
def sbrdf_node_kinds():
    return [Broken, DiskFull]
'''


def plugin_graph(tmp_path, node: str) -> Path:
    (tmp_path / "hostile_plugin.py").write_text(PLUGIN)
    path = tmp_path / "graph.yaml"
    path.write_text(f"name: g\nstore: {tmp_path / 'store'}\nnodes:\n  a: {{kind: {node}}}\n")
    return path


def test_an_unexpected_exception_is_one_line_and_v_shows_the_traceback(tmp_path):
    path = plugin_graph(tmp_path, "Broken")
    r = sbrdf("-p", "hostile_plugin", "validate", str(path), env={"PYTHONPATH": str(tmp_path)})
    no_traceback(r)
    assert r.returncode == 1 and "sbrdf: error: KeyError: 'no such key'" in r.stderr, r.stderr
    assert "run with -v for the traceback" in r.stderr and len(r.stderr.strip().splitlines()) <= 3
    r = sbrdf("-v", "-p", "hostile_plugin", "validate", str(path), env={"PYTHONPATH": str(tmp_path)})
    assert r.returncode == 1 and "Traceback" in r.stderr and "KeyError" in r.stderr


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_out_of_disk_space_is_said_plainly(tmp_path):
    path = plugin_graph(tmp_path, "DiskFull")
    r = sbrdf("-p", "hostile_plugin", "run", "-q", str(path), env={"PYTHONPATH": str(tmp_path)})
    no_traceback(r)
    assert r.returncode != 0 and "out of disk space on " in r.stderr, r.stderr


# -- nested plugin references: {device: NAME, params: {...}} follow NAME's declarations --------------------------


def test_a_camera_devices_params_are_checked_at_validation(tmp_path, capsys):
    path = tmp_path / "graph.yaml"
    path.write_text(textwrap.dedent(f"""\
        name: g
        store: {tmp_path / 'store'}
        nodes:
          capture:
            kind: Capture
            plugin: virtual-folder
            params:
              path: {tmp_path / 'capture'}
              camera:
                device: virtual-camera
                params: {{width: 64, height: 48, focal_mm: 12, texels: big}}
        """))
    rc, out = validate(capsys, path)
    assert rc == 2, out
    assert f"{path}:11: unknown parameter 'focal_mm' for device 'virtual-camera'" in out
    assert f"{path}:11: device 'virtual-camera': parameter 'texels' should be list, got str 'big'" in out
    path.write_text(path.read_text().replace("focal_mm: 12, texels: big", "focal_px: 80"))
    rc, out = validate(capsys, path)
    assert rc == 0, out


def test_a_motors_device_params_are_checked_at_validation(tmp_path, capsys):
    path = tmp_path / "graph.yaml"
    path.write_text(textwrap.dedent(f"""\
        name: g
        store: {tmp_path / 'store'}
        nodes:
          capture:
            kind: Capture
            plugin: gonio
            params:
              path: {tmp_path / 'capture'}
              motors:
                arm: {{device: ptu, params: {{port: sim, tolerance_deg: 99}}}}
                light: {{device: no-such-motor, params: {{port: sim}}}}
        """))
    rc, out = validate(capsys, path)
    assert rc == 2, out
    assert f"{path}:10: device 'ptu': parameter 'tolerance_deg' = 99.0 is outside [0.0, 10.0]" in out
    assert f"{path}:11: motors.light.device: unknown device plugin 'no-such-motor'" in out


def test_merl_from_model_params_are_checked_against_the_model(tmp_path, capsys):
    path = tmp_path / "graph.yaml"
    path.write_text(f"name: g\nstore: {tmp_path / 'store'}\nnodes:\n"
                    "  merl: {kind: MerlFromModel, params: {model: cook-torrance, params: {alpha: -1, shine: 2}}}\n")
    rc, out = validate(capsys, path)
    assert rc == 2 and f"{path}:4: MerlFromModel node: params.alpha = -1 is outside" in out, out
    assert "params.shine: model 'cook-torrance' has no parameter 'shine'" in out


def test_a_plugin_module_that_does_not_import_is_named_without_a_traceback(tmp_path):
    path = sample_graph(tmp_path, "seed: 1")
    r = sbrdf("-p", "no_such_plugin_module", "validate", str(path))
    no_traceback(r)
    assert r.returncode == 2 and "sbrdf: error: -p no_such_plugin_module: the plugin module cannot be imported" \
        in r.stderr, r.stderr


@pytest.mark.parametrize("plan, says", [
    ("light_pos: [[0, 0, 500], [1, 2]]", "light_pos[1] should be [x, y, z] in mm (three finite numbers), got [1, 2]"),
    ("light_pos: [a, b]", "light_pos[0] should be [x, y, z] in mm"),
    ("light_pos: [[0, 0, 500]]\ncamera_pos: [[0, 0, 500], [0, 0, 400]]", "camera_pos has 2 positions, light_pos 1"),
    ("camera_pos: [[0, 0, 500]]", "camera_pos needs light_pos"),
])
def test_a_sample_model_pose_plan_is_checked_at_validation(tmp_path, capsys, plan, says):
    rc, out = validate(capsys, sample_graph(tmp_path, plan))
    assert rc == 2 and ": SampleModel node: " in out and says in out, out


@pytest.mark.parametrize("line, says", [
    (f"limits: {{max_memory: {'9' * 400}}}", "limits: max_memory: not a size: an integer of 1329 bits"),
    ("store: /tmp/" + "a" * 5000, "cannot be opened: File name too long"),
    ('store: "/tmp/a\\0b"', "cannot be opened: embedded null byte"),
])
def test_sizes_and_store_paths_no_system_call_takes_are_line_errors(tmp_path, capsys, line, says):
    path = sample_graph(tmp_path, "seed: 1")
    text = path.read_text()
    if line.startswith("store:"):
        text = text.replace(f"store: {tmp_path / 'store'}", line)
    else:
        text = text.replace("nodes:", line + "\nnodes:")
    path.write_text(text)
    rc, out = validate(capsys, path)
    assert rc == 2 and f"{path}:" in out and says in out, out


def test_a_gonio_read_mapping_is_checked_by_the_folder_readers_declarations(tmp_path, capsys):
    path = tmp_path / "graph.yaml"
    path.write_text(textwrap.dedent(f"""\
        name: g
        store: {tmp_path / 'store'}
        nodes:
          capture:
            kind: Capture
            plugin: gonio
            params:
              path: {tmp_path / 'capture'}
              motors:
                arm: {{device: ptu, params: {{port: sim}}}}
              read: {{saturation: 2, bogus: 1}}
        """))
    rc, out = validate(capsys, path)
    assert rc == 2, out
    assert f"{path}:11: Capture plugin 'gonio': read (the folder reader): parameter 'saturation' = 2.0 is outside" in out
    assert "unknown parameter 'bogus' for read (the folder reader)" in out
    path.write_text(path.read_text().replace("saturation: 2, bogus: 1", "path: elsewhere"))
    rc, out = validate(capsys, path)
    assert rc == 2 and "read: ['path'] are set by the gonio source itself" in out, out
