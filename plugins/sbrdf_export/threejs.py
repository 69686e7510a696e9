"""An exported glTF rendered by three.js in headless Chromium: a glTF renderer that is not the project's.

Why: the round trip of an export is judged by a program that reads glTF as
any viewer does (``GLTFLoader``, ``MeshPhysicalMaterial`` with
``KHR_materials_specular``), not by the project's own reading of the file.
The page loads the file, places the quad in the sample frame (glTF is Y-up,
the project's scenes Z-up: the root is turned +90° about X, and scaled so
the quad has the scene plane's size), adds point lights (three.js's
physically based ``PointLight``: irradiance = intensity cos θ / d², decay 2,
no cutoff, the project's and Mitsuba's convention), no ambient or
environment light, and renders into a float render target with linear
output and no tone mapping; the pixels come back as linear radiance.  With
``supersample`` k, the page renders k× the resolution and the result is the
mean of each k×k block: the same sub-pixel points as a k² stratified,
unjittered sampler (the ``cpu`` renderer's ``antialias``).

Where three.js (r187) differs from glTF's Appendix B, it is what a glTF
viewer shows: roughness is floored at 0.045, the diffuse term is weighted by
(1 − F) per channel rather than by (1 − max F), and the specular lobe gets a
multiple-scattering compensation 1 + F0 (1/E_ss − 1) (small for the weak,
glossy lobes of measured dielectrics).

Needs ``chromium``, ``chromium-driver``, selenium, and three.js from npm:
``npm install --prefix .cache/npm three``; :func:`find_three` says where it
looked.
"""

from __future__ import annotations

import base64
import functools
import http.server
import json
import os
import shutil
import subprocess
import threading
from pathlib import Path

import numpy as np

__all__ = ["CHROME_FLAGS", "available", "find_three", "render_gltf"]

CHROME_FLAGS = ("--headless", "--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
                "--window-size=800,600")
ROOT = Path(__file__).resolve().parents[2]

PAGE = """<!doctype html>
<html><head><meta charset="utf-8">
<script type="importmap">{"imports": {"three": "/three/build/three.module.js",
                                      "three/addons/": "/three/examples/jsm/"}}</script>
</head><body>
<script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
const P = %(params)s;
window.SBRDF = {done: false, error: null};
try {
  const W = P.width, H = P.height;
  const renderer = new THREE.WebGLRenderer({antialias: false, alpha: false});
  renderer.setPixelRatio(1);
  renderer.setSize(W, H, false);
  renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
  renderer.toneMapping = THREE.NoToneMapping;
  const target = new THREE.WebGLRenderTarget(W, H, {type: THREE.FloatType, format: THREE.RGBAFormat,
    minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, depthBuffer: true});
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0, 0, 0);
  const cam = new THREE.PerspectiveCamera(P.fov, W / H, 0.01, 1000);
  cam.up.set(...P.up);
  cam.position.set(...P.position);
  cam.lookAt(new THREE.Vector3(...P.look_at));
  for (const l of P.lights) {
    const light = new THREE.PointLight(new THREE.Color(...l.color), l.intensity, 0, 2);
    light.position.set(...l.position);
    scene.add(light);
  }
  new GLTFLoader().load(P.url, (gltf) => {
    try {
      const root = gltf.scene;
      root.rotation.x = Math.PI / 2;  // glTF +Y (the sample's normal) -> +Z, glTF -Z (the sample's +y) -> +Y
      root.scale.setScalar(P.scale);
      root.position.set(...P.offset);
      scene.add(root);
      renderer.setRenderTarget(target);
      renderer.render(scene, cam);
      const buf = new Float32Array(W * H * 4);
      renderer.readRenderTargetPixels(target, 0, 0, W, H, buf);
      const bytes = new Uint8Array(buf.buffer);
      let s = '';
      for (let i = 0; i < bytes.length; i += 32768) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 32768));
      window.SBRDF.pixels = btoa(s);
      window.SBRDF.material = gltf.scene.children[0].material.type;
      window.SBRDF.done = true;
    } catch (e) { window.SBRDF.error = String(e); }
  }, undefined, (e) => { window.SBRDF.error = String(e); });
} catch (e) { window.SBRDF.error = String(e); }
</script></body></html>
"""


def find_three() -> Path | None:
    """The ``three`` npm package: ``$SBRDF_THREE``, ``.cache/npm`` or ``node_modules`` of the checkout, or node's."""
    for cand in (os.environ.get("SBRDF_THREE"), ROOT / ".cache" / "npm" / "node_modules" / "three",
                 ROOT / "node_modules" / "three"):
        if cand and Path(cand, "build", "three.module.js").exists():
            return Path(cand)
    node = shutil.which("node")
    if node:
        r = subprocess.run([node, "-e", "console.log(require.resolve('three/package.json'))"], capture_output=True,
                           text=True)
        if r.returncode == 0 and r.stdout.strip():
            return Path(r.stdout.strip()).parent
    return None


def available() -> str | None:
    """None when :func:`render_gltf` can run, else why not (with the install command)."""
    for exe in ("chromium", "chromedriver"):
        if shutil.which(exe) is None:
            return f"{exe} is not installed (Debian: apt-get install chromium chromium-driver)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed: pip install 'sbrdf[interchange]'"
    if find_three() is None:
        return "three.js is not installed: npm install --prefix .cache/npm three"
    return None


class _Handler(http.server.SimpleHTTPRequestHandler):
    """Serves ``/three/...`` from the three package, ``/model/...`` from the export, ``/`` the page."""

    def __init__(self, *args, three: Path, model: Path, page: str, **kw):
        self.three, self.model, self.page = three, model, page
        super().__init__(*args, **kw)

    def translate_path(self, path):
        path = path.split("?", 1)[0]
        for prefix, base in (("/three/", self.three), ("/model/", self.model)):
            if path.startswith(prefix):
                return str(base / path[len(prefix):])
        return "/nonexistent"

    def do_GET(self):
        if self.path.split("?", 1)[0] in ("/", "/index.html"):
            body = self.page.encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        super().do_GET()

    def guess_type(self, path):
        return "text/javascript" if str(path).endswith(".js") else super().guess_type(path)

    def log_message(self, *args):  # quiet: the tests and benchmarks print their own figures
        pass


def render_gltf(path: str, camera: dict, lights: list[dict], *, plane_size: float, size_mm, supersample: int = 2,
                offset=(0.0, 0.0, 0.0), timeout: float = 300.0) -> np.ndarray:
    """Render the glTF at ``path`` with three.js; linear ``(H, W, 3)`` float32 radiance.

    ``camera``: ``position``, ``look_at``, ``up``, ``fov_deg`` (vertical), ``resolution`` ``[W, H]`` in
    the scene frame (Z up); ``lights``: ``{"position": (3,), "intensity": (3,) or float}`` point lights;
    ``plane_size``: the width the quad gets in the scene (its glTF width is ``size_mm[0]`` mm), centred at
    ``offset``.
    """
    from sbrdf_core.extras import require

    webdriver = require("selenium.webdriver", extra="interchange", feature="rendering glTF with three.js")
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.support.ui import WebDriverWait

    three = find_three()
    if three is None:
        raise RuntimeError(available())
    k = int(supersample)
    W, H = (int(x) for x in camera["resolution"])
    params = {
        "width": W * k, "height": H * k, "fov": float(camera["fov_deg"]),
        "position": [float(x) for x in camera["position"]], "look_at": [float(x) for x in camera["look_at"]],
        "up": [float(x) for x in camera.get("up", (0, 0, 1))],
        "lights": [{"position": [float(x) for x in lt["position"]],
                    "color": [float(x) for x in np.broadcast_to(np.asarray(lt["intensity"], float), 3) /
                              max(float(np.max(lt["intensity"])), 1e-30)],
                    "intensity": float(np.max(lt["intensity"]))} for lt in lights],
        "scale": float(plane_size) / (float(size_mm[0]) / 1000.0), "offset": [float(x) for x in offset],
        "url": f"/model/{Path(path).name}",
    }
    page = PAGE % {"params": json.dumps(params)}
    handler = functools.partial(_Handler, three=three, model=Path(path).resolve().parent, page=page)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    opts = webdriver.ChromeOptions()
    for flag in CHROME_FLAGS:
        opts.add_argument(flag)
    if shutil.which("chromium"):
        opts.binary_location = shutil.which("chromium")
    driver = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)
    try:
        driver.get(f"http://127.0.0.1:{server.server_address[1]}/")
        WebDriverWait(driver, timeout, poll_frequency=0.2).until(
            lambda d: d.execute_script("return window.SBRDF && (window.SBRDF.done || window.SBRDF.error !== null)"))
        error = driver.execute_script("return window.SBRDF.error")
        if error:
            raise RuntimeError(f"three.js could not render {path}: {error}")
        data = base64.b64decode(driver.execute_script("return window.SBRDF.pixels"))
    finally:
        driver.quit()
        server.shutdown()
        server.server_close()
    img = np.frombuffer(data, np.float32).reshape(H * k, W * k, 4)[::-1, :, :3]  # GL rows run bottom-up
    return img.reshape(H, k, W, k, 3).mean(axis=(1, 3)).astype(np.float32)
