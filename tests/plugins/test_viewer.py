"""The viewer (``sbrdf view``): the self-contained page, the command, and the page in a real headless browser.

Browser tests need Debian's ``chromium`` and ``chromium-driver`` and selenium; they skip with the reason where
those are absent (CI installs them).  Tolerance of the page against the ``gl`` renderer: relative RMS ≤ 2 % over
the plane (measured ≈ 0.6 %: 8-bit display quantisation and a few texel-boundary pixels).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from sbrdf_core.registry import Registry

TOL = 0.02
ROOT = Path(__file__).resolve().parents[2]
VIEW = {"eye": [0.3, -2.2, 1.6], "light": [0.8, -1.0, 1.5], "intensity": 6.0, "width": 320, "height": 240}


@pytest.fixture(scope="module")
def reg():
    return Registry(extra=["sbrdf_viewer"])


@pytest.fixture(scope="module")
def store(tmp_path_factory, reg):
    """A small synthetic Lafortune capture, its fit (with held-out samples) and 8-bit textures."""
    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner

    tmp = tmp_path_factory.mktemp("viewer")
    graph = tmp / "g.yaml"
    graph.write_text(f"""
name: viewer
store: {tmp / 'runs'}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [24, 16], poses: 60, model: lafortune, noise: 0.005, seed: 3}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lafortune, holdout: 0.1}}}}
  textures: {{kind: Quantize, plugin: mcallister8, in: {{params: fit, samples: reflectance}}}}
""")
    Runner(reg).run(load_graph(str(graph), reg))
    return tmp / "runs"


def test_page_is_self_contained_and_embeds_maps_errors_and_samples(reg, store, tmp_path):
    from sbrdf_viewer.page import fragment_source, write_page

    path, info = write_page(reg, str(store / "fit"), tmp_path, sample_grid=4)
    text = path.read_text()
    assert not re.search(r"""(src|href)\s*=\s*["'](?!#)""", text), "the page must load nothing from outside"
    assert "http://" not in text and "https://" not in text
    data = info["data"]
    names = [c["name"] for c in data["channels"]]
    assert {"rho_d.r", "exponent_1", "rms", "rms_holdout", "samples"} <= set(names)
    assert data["samples"]["url"].endswith("reflectance") and data["samples"]["grid"] == [4, 4]
    assert data["samples"]["total"] > 16 * 10
    model = reg.create("brdf-model", "lafortune", {})
    fs = fragment_source(model)
    assert fs.startswith("#version 300 es") and model.glsl() in fs  # the model's own GLSL, one source of truth
    # a TextureSet is decoded through its quantizer; it also carries the quantization error map
    _, info = write_page(reg, str(store / "textures"), tmp_path / "t", sample_grid=2)
    assert info["data"]["quantizer"] == "mcallister8"
    assert "quantization_error" in [c["name"] for c in info["data"]["channels"]]
    # maps larger than max_size are shown every k-th texel
    _, info = write_page(reg, str(store / "fit"), tmp_path / "s", sample_grid=0, max_size=10)
    assert info["data"]["stride"] == 3 and info["data"]["shape"] == [6, 8] and info["data"]["samples"] is None


def test_view_command_writes_and_serves_on_localhost(store, tmp_path):
    from sbrdf_core.cli import main

    assert main(["-p", "sbrdf_viewer", "view", str(store / "fit"), "--no-serve", "--out", str(tmp_path / "a")]) == 0
    assert (tmp_path / "a" / "index.html").stat().st_size > 10_000
    assert main(["-p", "sbrdf_viewer", "view", str(store / "nowhere"), "--no-serve"]) == 2
    proc = subprocess.Popen([sys.executable, "-m", "sbrdf_core.cli", "-p", "sbrdf_viewer", "view", str(store / "fit"),
                             "--port", "0", "--out", str(tmp_path / "b"), "--sample-grid", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT)
    try:
        url = None
        for line in proc.stdout:
            m = re.search(r"serving (http://127\.0\.0\.1:\d+/index\.html)", line)
            if m:
                url = m.group(1)
                break
        assert url, "no URL printed"
        body = urllib.request.urlopen(url, timeout=10).read()
        assert b"sbrdf-data" in body
    finally:
        proc.terminate()
        proc.wait(timeout=10)


# -- in a real browser -------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def driver():
    from sbrdf_viewer.check import browser, browser_available

    why = browser_available()
    if why:
        pytest.skip(why)
    d = browser()
    yield d
    d.quit()


@pytest.mark.parametrize("node", ["fit", "textures"])
def test_page_matches_the_gl_renderer(gl, reg, store, tmp_path, driver, node):
    from sbrdf_core.nodes.render import display_exposure
    from sbrdf_viewer.check import compare, console_errors, gl_reference, load, screenshot_linear
    from sbrdf_viewer.page import write_page

    url = str(store / node)
    path, info = write_page(reg, url, tmp_path, sample_grid=4)
    aspect = info["data"]["size_mm"][1] / info["data"]["size_mm"][0]
    ref = gl_reference(reg, url, aspect=aspect, **VIEW)
    exposure = display_exposure(ref)
    state = load(driver, path, exposure=exposure, ui=0, **VIEW)
    assert state == {"ready": True, "errors": []}
    assert console_errors(driver) == []
    shot = screenshot_linear(driver, exposure)
    assert shot.shape == ref.shape
    result = compare(shot, ref, exposure)
    assert result["pixels"] > 0.3 * ref.shape[0] * ref.shape[1]
    assert result["rel_rms"] < TOL, result


def test_sphere_false_colour_and_texel_plot_without_errors(reg, store, tmp_path, driver):
    from sbrdf_viewer.check import console_errors, load
    from sbrdf_viewer.page import write_page

    path, _ = write_page(reg, str(store / "fit"), tmp_path, sample_grid=4)
    assert load(driver, path, object="sphere", mode="false", channel="rms_holdout", texel="12,8")["errors"] == []
    picked = driver.execute_script("return window.sbrdfViewer.state.picked")
    assert picked[2] > 10  # the nearest embedded texel's samples were plotted
    driver.execute_script("window.sbrdfViewer.set({object: 'plane', mode: 'shaded'})")
    assert driver.execute_script("return window.sbrdfViewer.errors") == []
    assert console_errors(driver) == []
    # the documentation's screenshots: the whole page at the default view, a texel's samples plotted; written
    # into docs/img with SBRDF_DOC_IMAGES=1 (a plain test run leaves the checkout unchanged)
    load(driver, path, texel="12,8")
    img = (ROOT / "docs" / "img" if os.environ.get("SBRDF_DOC_IMAGES") else tmp_path) / "viewer.png"
    img.parent.mkdir(exist_ok=True)
    driver.set_window_size(1100, 720)
    driver.save_screenshot(str(img))
    driver.set_window_size(1400, 1000)
    load(driver, path, mode="false", channel="rms_holdout", object="sphere", eye="0,-3.2,1.4", width=320, height=240)
    driver.find_element("id", "view").screenshot(str(img.with_name("viewer-false-colour.png")))
    assert img.stat().st_size > 10_000 and img.with_name("viewer-false-colour.png").stat().st_size > 5_000


def test_every_installed_model_glsl_compiles_as_glsl_es_300(reg, driver):
    """The fragment shader the page builds, for every installed model, compiles under WebGL2 (ES 3.00)."""
    from sbrdf_viewer.page import VERTEX, fragment_source

    driver.get("about:blank")
    failures = {}
    for name in reg.names("brdf-model"):
        try:
            model = reg.create("brdf-model", name, {})
        except Exception as e:  # noqa: BLE001 - a model that needs configuration (a table file) is not for this check
            failures[name] = f"not created with defaults: {e}"
            continue
        log = driver.execute_script("""
            const gl = document.createElement('canvas').getContext('webgl2');
            const out = [];
            for (const [t, src] of [[gl.VERTEX_SHADER, arguments[0]], [gl.FRAGMENT_SHADER, arguments[1]]]) {
              const s = gl.createShader(t); gl.shaderSource(s, src); gl.compileShader(s);
              if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) out.push(gl.getShaderInfoLog(s));
            }
            return out.join('\\n');""", VERTEX, fragment_source(model))
        if log:
            failures[name] = log
    compile_errors = {k: v for k, v in failures.items() if not v.startswith("not created")}
    assert not compile_errors, compile_errors
    assert len(reg.names("brdf-model")) - len(failures) >= 5  # the built-in models at least
