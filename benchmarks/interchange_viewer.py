"""The viewer page (``sbrdf view``) against the ``gl`` renderer, and how long writing the page takes.

A synthetic 1-lobe Lafortune capture (``--quick``: 32×32 texels, 80 poses; full: 128×128 texels, 200 poses) is
fitted (LM, 10 % held out); the page of the fit is written (``sample_grid`` 16, the default) and timed; headless
Chromium (SwiftShader WebGL2) draws the plane at a fixed eye and light, and the canvas is compared with the ``gl``
renderer's image of the same scene (:mod:`sbrdf_viewer.check`: relative RMS over the plane, 8-bit sRGB undone at the
same exposure).  Without chromium, chromedriver or selenium the error is reported as ``nan``.  The last line is

    interchange_viewer: viewer_vs_gl_rel_err=... page_bytes=... write_s=...
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
VIEW: dict[str, Any] = {"eye": [0.3, -2.2, 1.6], "light": [0.8, -1.0, 1.5], "intensity": 6.0, "width": 480,
                        "height": 360}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="32×32 texels, 80 poses")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "plugins"))  # before the package is installed through its entry point

    from sbrdf_core.graph import load_graph
    from sbrdf_core.nodes.render import display_exposure
    from sbrdf_core.registry import Registry
    from sbrdf_core.runner import Runner
    from sbrdf_viewer.check import browser, browser_available, compare, console_errors, gl_reference, load, screenshot_linear
    from sbrdf_viewer.page import write_page

    texels, poses = ((32, 32), 80) if args.quick else ((128, 128), 200)
    reg = Registry(extra=["sbrdf_viewer"])
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        graph = tmp / "g.yaml"
        graph.write_text(f"""
name: viewer-bench
store: {tmp / 'runs'}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: {list(texels)}, poses: {poses}, model: lafortune, noise: 0.005, seed: 3}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lafortune, holdout: 0.1}}}}
""")
        Runner(reg).run(load_graph(str(graph), reg))
        url = str(tmp / "runs" / "fit")
        t0 = time.perf_counter()
        path, info = write_page(reg, url, tmp / "page")
        write_s = time.perf_counter() - t0
        print(f"page: {info['bytes']} bytes, written in {write_s:.3f} s ({texels[0]}×{texels[1]} texels, "
              f"{info['data']['samples']['total']} samples embedded)")
        rel = float("nan")
        why = browser_available()
        if why:
            print(f"browser check skipped: {why}")
        else:
            aspect = info["data"]["size_mm"][1] / info["data"]["size_mm"][0]
            ref = gl_reference(reg, url, aspect=aspect, **VIEW)
            exposure = display_exposure(ref)
            d = browser()
            try:
                t1 = time.perf_counter()
                state = load(d, path, exposure=exposure, ui=0, **VIEW)
                load_s = time.perf_counter() - t1
                errors = console_errors(d) + list(state["errors"] if state else ["page did not start"])
                shot = screenshot_linear(d, exposure)
            finally:
                d.quit()
            result = compare(shot, ref, exposure)
            rel = result["rel_rms"]
            print(f"page load {load_s:.2f} s, console errors: {errors or 'none'}; {result['pixels']} plane pixels, "
                  f"{100 * result['frac_over_4_of_255']:.2f} % differ by more than 4/255")
    print(f"interchange_viewer: viewer_vs_gl_rel_err={rel:.4g} page_bytes={info['bytes']} write_s={write_s:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
