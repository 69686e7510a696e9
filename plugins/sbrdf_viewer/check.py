"""Checking the page against the ``gl`` renderer in a real headless browser (tests, benchmark).

The page and the renderer draw the same scene (:func:`~sbrdf_viewer.page.scene_for`: the plane, one point light,
no antialiasing, ``nearest`` lookups); the page's canvas (8-bit sRGB at the exposure it was given) is turned back
into linear radiance and compared with the renderer's linear image clipped at the same exposure, over the pixels
the plane covers, eroded by one pixel (the silhouette rasterises differently by a pixel).

Browser: Debian's ``chromium`` and ``chromium-driver`` through selenium, headless, WebGL2 on SwiftShader.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from sbrdf_core.extras import require

__all__ = ["CHROME_FLAGS", "browser", "browser_available", "compare", "console_errors", "gl_reference", "load",
           "screenshot_linear"]

CHROME_FLAGS = ("--headless", "--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
                "--window-size=1400,1000")


def browser_available() -> str | None:
    """None when a headless check can run, else why not."""
    for exe in ("chromium", "chromedriver"):
        if shutil.which(exe) is None:
            return f"{exe} is not installed (Debian: apt-get install chromium chromium-driver)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install selenium)"
    return None


def browser():
    """A headless Chromium driven by selenium, logging the console."""
    webdriver = require("selenium.webdriver", extra="interchange", feature="the viewer's browser check")
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    for flag in CHROME_FLAGS:
        opts.add_argument(flag)
    exe = shutil.which("chromium")
    if exe:
        opts.binary_location = exe
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)


def load(driver, page: Path, **view) -> dict:
    """Open the page with a view given as URL parameters; the viewer's state and errors once it is ready."""
    from urllib.parse import urlencode

    q = {k: ",".join(repr(float(x)) for x in v) if isinstance(v, (list, tuple)) else v for k, v in view.items()}
    driver.get(Path(page).resolve().as_uri() + ("?" + urlencode(q) if q else ""))
    return driver.execute_script("const v = window.sbrdfViewer; return v ? {ready: v.ready, errors: v.errors} : null;")


def console_errors(driver) -> list[str]:
    """Console messages of level SEVERE since the last call."""
    return [e["message"] for e in driver.get_log("browser") if e.get("level") == "SEVERE"]


def screenshot_linear(driver, exposure: float, png: str | Path | None = None) -> np.ndarray:
    """The canvas as linear radiance ``(H, W, 3)``: 8-bit sRGB undone, divided by the exposure."""
    from sbrdf_core.io import read_png

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(png) if png else Path(tmp) / "canvas.png"
        driver.find_element("id", "view").screenshot(str(path))
        s = read_png(str(path))[..., :3].astype(np.float64) / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4) / exposure


def gl_reference(registry, url: str, eye, light, intensity: float, width: int, height: int,
                 aspect: float = 1.0, fov_deg: float = 40.0) -> np.ndarray:
    """The ``gl`` renderer's linear image of the scene the page shows (registry plugin ``gl``)."""
    import dask

    from sbrdf_core.nodes.render import open_material

    from .page import scene_for

    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "scene.yaml"
        scene.write_text(scene_for("input", eye, light, intensity, width, height, aspect, fov_deg))
        renderer = registry.create("renderer", "gl", {"scene": str(scene)})
        if hasattr(renderer, "bind"):
            renderer.bind(registry)
        material = open_material(registry, url)
        prepared = dask.compute(renderer.prepare(material))[0] if hasattr(renderer, "prepare") else None
        return np.asarray(renderer.render(material, prepared=prepared).image, np.float64)


def compare(shot: np.ndarray, ref: np.ndarray, exposure: float) -> dict:
    """Relative RMS of the page against the renderer over the plane (eroded one pixel), both clipped at the exposure."""
    ref_c = np.clip(ref * exposure, 0.0, 1.0) / exposure
    m = np.pad(ref.sum(-1) > 0, 1)
    mask = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]  # eroded by one pixel
    d = shot[mask] - ref_c[mask]
    rel = float(np.sqrt(np.mean(d ** 2)) / max(np.sqrt(np.mean(ref_c[mask] ** 2)), 1e-30))
    big = float(np.mean(np.abs(d).max(-1) * exposure > 4 / 255))
    return {"rel_rms": rel, "pixels": int(mask.sum()), "frac_over_4_of_255": big}
