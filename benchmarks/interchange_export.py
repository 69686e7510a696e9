"""The exr-set, materialx, usd and mitsuba exporters: export times, conversion errors, Mitsuba against ``cpu``.

Two fitted materials of a synthetic sample (``SampleModel``, noise-free;
``--quick``: 16×12 texels, full: 64×48): a ``cook-torrance`` GGX fit, which
the GGX conversion reads exactly, and a 1-lobe ``lafortune`` fit, which it
cannot.  Each is exported by every exporter (times: the Export node's wall
time, conversion included), and the Mitsuba scene (the exporter's default
scene: the sample as a plane under a point light, 2×2 unjittered sub-pixel
samples, box filter) is rendered with Mitsuba 3 (``scalar_rgb``) and compared
with the project's ``cpu`` render of the same scene file: relative RMS over
the pixels the plane covers.  For cook-torrance what remains is Mitsuba's
BSDF against ours (separable against height-correlated Smith G, exact
dielectric Fresnel against Schlick's); for Lafortune the GGX conversion's
error adds to it.  Without Mitsuba the errors are ``nan``.  The last line is

    interchange_export: mitsuba_vs_cpu_rel_err=... materialx_s=... usd_s=... exr_s=... mitsuba_s=...
        mitsuba_vs_cpu_lafortune_rel_err=... lafortune_conversion_err=...

(``mitsuba_vs_cpu_rel_err`` and the times for the cook-torrance fit;
``lafortune_conversion_err``: the mean per-texel held-out relative error of
the GGX conversion of the Lafortune fit.)
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXPORTERS = {"exr": "exr-set", "materialx": "materialx", "usd": "usd", "mitsuba": "mitsuba"}


def measure(model: str, texels, resolution, tmp: Path) -> dict:
    from sbrdf_core.graph import load_graph
    from sbrdf_core.registry import Registry
    from sbrdf_core.runner import Runner
    from sbrdf_core.store import open_artifact
    from sbrdf_export.mitsuba import DEFAULT_SCENE, render

    store = tmp / model
    scene = tmp / f"{model}.yaml"
    scene.write_text(DEFAULT_SCENE.format(w=resolution[0], h=resolution[1], sy=round(2.0 * texels[1] / texels[0], 6)))
    have = {k: v for k, v in EXPORTERS.items()
            if importlib.util.find_spec({"materialx": "MaterialX", "usd": "pxr"}.get(k, "numpy")) is not None}
    nodes = "".join(f"  {k}: {{kind: Export, plugin: {v}, in: {{material: fit}}}}\n" for k, v in have.items())
    text = textwrap.dedent(f"""\
        name: export-{model}
        store: {store}
        nodes:
          a: {{kind: SampleModel, params: {{model: {model}, texels: {list(texels)}, size_mm: [100.0, {100.0 * texels[1] / texels[0]}], poses: 150, seed: 5}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: a}}, params: {{model: {model}}}}}
          cpu: {{kind: Render, plugin: cpu, in: {{material: fit}}, params: {{scene: {scene}}}}}
        """)
    text += nodes.replace("plugin: mitsuba, in: {material: fit}}", f"plugin: mitsuba, in: {{material: fit}}, params: {{scene: {scene}}}}}")
    runner = Runner(registry=Registry(extra=["sbrdf_export"]), progress=False)
    runner.run(load_graph(text, runner.registry))
    out = {}
    for k in EXPORTERS:
        out[f"{k}_s"] = open_artifact(f"{store}/{k}").attrs["run"]["wall_s"] if k in have else float("nan")
    mi = open_artifact(f"{store}/mitsuba")
    out["conversion_err"] = mi.attrs.get("error_mean")
    out["rel_err"] = float("nan")
    if importlib.util.find_spec("mitsuba") is not None:
        t0 = time.perf_counter()
        image = render(str(store / "mitsuba" / "scene.xml"))
        out["mitsuba_render_s"] = time.perf_counter() - t0
        cpu = open_artifact(f"{store}/cpu").read("image")
        lit = cpu.max(-1) > 0
        out["rel_err"] = float(np.sqrt(((image - cpu) ** 2)[lit].mean() / (cpu ** 2)[lit].mean()))
        out["lit_pixels"] = int(lit.sum())
        out["images"] = (cpu, image)
    return out


def write_figure(path: Path, cpu: np.ndarray, image: np.ndarray) -> None:
    """cpu | Mitsuba | |difference| × 10, one exposure, sRGB."""
    from sbrdf_core.io import linear_to_srgb8, write_png
    from sbrdf_core.nodes.render import display_exposure

    e = display_exposure(cpu)
    gap = np.zeros((cpu.shape[0], 4, 3))
    write_png(str(path), linear_to_srgb8(np.concatenate([cpu, gap, image, gap, 10 * np.abs(image - cpu)], 1), e))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="16×12 texels, 160×120 pixels")
    ap.add_argument("--figure", type=Path, help="write cpu | Mitsuba | 10×|difference| of the lafortune fit here")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "plugins"))  # before the package is installed through its entry point
    texels, resolution = ((16, 12), (160, 120)) if args.quick else ((64, 48), (320, 240))
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for model in ("cook-torrance", "lafortune"):
            r = results[model] = measure(model, texels, resolution, Path(tmp))
            print(f"{model} {texels[0]}×{texels[1]} texels: " + ", ".join(
                f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items() if k != "images"),
                flush=True)
    if args.figure and "images" in results["lafortune"]:
        write_figure(args.figure, *results["lafortune"]["images"])
    ct, laf = results["cook-torrance"], results["lafortune"]
    print(f"interchange_export: mitsuba_vs_cpu_rel_err={ct['rel_err']:.4g} materialx_s={ct['materialx_s']:.4g} "
          f"usd_s={ct['usd_s']:.4g} exr_s={ct['exr_s']:.4g} mitsuba_s={ct['mitsuba_s']:.4g} "
          f"mitsuba_vs_cpu_lafortune_rel_err={laf['rel_err']:.4g} lafortune_conversion_err={laf['conversion_err']:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
