"""Exports judged by other programs: the glTF rendered by three.js, the Mitsuba scene by Mitsuba 3, each against ``cpu``.

Two fitted materials, each exported by ``gltf`` and ``mitsuba`` (default
conversion parameters) and rendered in one scene (the sample as a 2-unit
plane seen from 50° under one point light, 2×2 unjittered sub-pixel samples;
``glossy_conversion_err`` and ``_flagged`` are the export's own median
per-texel error and flagged fraction):

``glossy``  the README demo's fit (graphs/demo.yaml up to ``fit``: a simulated
            capture of a 1-lobe Lafortune material, 128×128 texels; ``--quick``
            32×32), Lafortune exponents around 60;
``rough``   a 1-lobe Lafortune fit of a ``SampleModel`` sample with exponent 6.

For each, the project's ``cpu`` render of the fit is the reference; the
exported ``.gltf`` is rendered by three.js (r187, ``GLTFLoader``, headless
Chromium, :mod:`sbrdf_export.threejs`) and the exported ``scene.xml`` by Mitsuba
3 (``scalar_rgb``).  ``*_rel_err`` is the relative L1 error over the pixels
the plane covers (eroded by one pixel: silhouettes rasterise differently)
Σ|a − b|/Σ|b|, b the ``cpu`` image (the measure of ``interchange_gltf``'s
``roundtrip_render_rel_err``); ``*_rms`` the relative RMS sqrt(Σ|a − b|²/Σ|b|²),
ruled by the brightest texels; ``*_peak_px`` the distance in pixels between
the highlights (maxima of the luminance averaged over a box 1/20 of the image
wide: 9×9 pixels at 160×120).  Pixels where
the ``cpu`` reference is brighter than 4× its 99th percentile are fireflies of the
fit itself (a Lafortune lobe that explodes outside the captured directions;
0.5 % of the pixels of the demo's fit at full size, up to 1e25): they are left
out and counted (``glossy_fireflies``).
``gltf_roughness_p50`` / ``_p99``: the demo's exported glTF roughness over
its texels.  ``usd_roughness_p50``, ``usd_clearcoat_roughness_p50`` and
``usd_conv_err_p50``: the demo's USD export (``usd``, UsdPreviewSurface with
its clearcoat, :mod:`sbrdf_lib.usd_preview`): the first lobe's and the
clearcoat's median roughness and the median per-texel conversion error
(``rough_usd_conv_err_p50`` the rough material's); ``nan`` without usd-core.
``*_gltf_from_samples_rel_err``: the same render round trip of a second glTF
export, ``source: samples`` (glTF's GGX fitted to the reflectance samples the
material was fitted to, not converted from the fit), against the same ``cpu``
render of the fit; ``*_gltf_samples_err_p50`` and
``*_gltf_from_samples_samples_err_p50``: the median per-texel error of each
export's glTF BRDF against the samples themselves (cos θ_i cos θ_o weighted
relative RMS, directions within 70°), what the material measured like.  Without three.js, chromium or Mitsuba, those figures are ``nan``.

    .venv/bin/python benchmarks/interchange_roundtrip.py --quick   # 32 x 32 texels, 160 x 120 pixels
    .venv/bin/python benchmarks/interchange_roundtrip.py           # 128 x 128 texels, 320 x 240 pixels

Last line: ``interchange_roundtrip: glossy_gltf_rel_err=... glossy_mitsuba_rel_err=... rough_gltf_rel_err=...
rough_mitsuba_rel_err=... gltf_roughness_p50=... gltf_roughness_p99=...`` plus the peak distances, the RMS
errors and the conversion's error and flagged fraction per material.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

SCENE = """\
camera: {{position: [0.0, -1.0, 1.2], look_at: [0.0, 0.05, 0.0], up: [0, 0, 1], fov_deg: 40, resolution: [{w}, {h}]}}
materials:
  sample: {{artifact: input, filter: bilinear}}
objects:
  - {{shape: plane, size: [2.0, 2.0]}}
lights:
  - {{type: point, position: [0.3, 0.6, 1.0], intensity: 2}}
antialias: 4
"""


#: The node holding each material's reflectance samples (the Fit node's input).
SAMPLES = {"glossy": "reflectance", "rough": "samples"}


def sample_errors(store: Path, kind: str) -> dict:
    """Median, over texels, of each glTF export's BRDF against the reflectance samples (:func:`sample_error`)."""
    from sbrdf_core.geometry import tile_directions
    from sbrdf_core.store import open_artifact
    from sbrdf_lib.convert import GLTF_MAPS, VIEW_THETA_DEG, ggx_model, gltf_brdf, sample_error

    smp = open_artifact(f"{store}/{SAMPLES[kind]}")
    f, v = smp.read("f_r"), smp.read("valid")
    V, U = f.shape[:2]
    wi, _, wo = tile_directions(tuple(smp.attrs["texels"]), tuple(smp.attrs["size_mm"]), (0, V), (0, U),
                                smp.read("light_pos"), smp.read("camera_pos"))
    f, v = f.reshape(V * U, -1, 3).astype(np.float64), v.reshape(V * U, -1)
    limit = np.cos(np.radians(VIEW_THETA_DEG))
    v = v & np.isfinite(f).all(-1) & (wi[..., 2] >= limit) & (wo[..., 2] >= limit)
    f = np.where(v[..., None], f, 0.0)
    out = {}
    for node in ("gltf", "gltf_samples"):
        art = open_artifact(f"{store}/{node}")
        maps = {k: art.read(f"maps/{k}").reshape(V * U, -1).astype(np.float64) for k in GLTF_MAPS}
        out[node] = float(np.median(sample_error(gltf_brdf(ggx_model(), maps, wi, wo), f, v, wi, wo)))
    return out


def material_nodes(kind: str, texels: int) -> str:
    """The graph nodes that make the material ``fit``: the demo's capture and fit, or a rough sample's."""
    if kind == "glossy":  # graphs/demo.yaml up to its fit
        return f"""\
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [{texels}, {texels}], poses: 96, model: lafortune, model_params: {{lobes: 1}}, noise: 0.01, seed: 1}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lafortune, model_params: {{lobes: 1}}}}}}
"""
    return f"""\
  samples: {{kind: SampleModel, params: {{model: lafortune, params: {{exponent_1: 6.0}}, texels: [{texels}, {texels}], poses: 150, seed: 4}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lafortune}}}}
"""


def compare(image: np.ndarray, ref: np.ndarray) -> dict:
    """Relative L1 and RMS over the plane's pixels (eroded by one), and the distance between the highlights.

    ``rel_err`` = Σ|a − b| / Σ|b| (the project's render round-trip measure), ``rms`` = sqrt(Σ|a − b|² / Σ|b|²)
    (ruled by the brightest texels); ``peak_px``: pixels between the maxima of the luminance averaged over a
    box 1/20 of the image wide, 9×9 at 160×120 (a highlight, not one sparkling texel); ``peak_ratio``: the
    reference's box luminance at the export's maximum over its own maximum.  Reference pixels
    brighter than 4× its 99th percentile are left out and counted (``fireflies``).
    """
    lit = ref.max(-1) > 0
    inner = lit.copy()
    inner[1:] &= lit[:-1]
    inner[:-1] &= lit[1:]
    inner[:, 1:] &= lit[:, :-1]
    inner[:, :-1] &= lit[:, 1:]
    # fireflies of the reference: a fitted Lafortune lobe that explodes outside the captured directions renders
    # up to 1e25 (the demo's fit at 128 x 128 texels has 0.5 % such pixels); no exported file can follow them
    y = ref.max(-1)
    top = np.percentile(y[inner], 99) if inner.any() else np.inf
    firefly = inner & (y > 4.0 * top)
    inner &= ~firefly
    d = (image - ref).astype(np.float64)
    r = ref.astype(np.float64)
    out = {"rel_err": float(np.abs(d)[inner].sum() / np.abs(r)[inner].sum()),
           "rms": float(np.sqrt((d**2)[inner].sum() / (r**2)[inner].sum())), "fireflies": int(firefly.sum())}

    half = max(1, round(ref.shape[1] / 40))  # the box is 1/20 of the image wide whatever the resolution

    def boxed(a):
        y = np.where(inner, a @ np.array([0.2126, 0.7152, 0.0722]), 0.0)
        p = np.pad(y, half)
        return sum(p[i:i + y.shape[0], j:j + y.shape[1]] for i in range(2 * half + 1) for j in range(2 * half + 1))

    b_image, b_ref = boxed(image), boxed(ref)
    at_image, at_ref = (np.unravel_index(np.argmax(b), b.shape) for b in (b_image, b_ref))
    out["peak_px"] = float(np.linalg.norm(np.subtract(at_image, at_ref)))
    # how bright the reference is where the export's highlight lies, over its own highlight: near 1 where the
    # reference's highlight is a plateau and the peak pixel's place says little
    out["peak_ratio"] = float(b_ref[at_image] / b_ref[at_ref]) if b_ref[at_ref] > 0 else float("nan")
    return out


def measure(kind: str, texels: int, resolution, tmp: Path) -> dict:
    from sbrdf_core.graph import load_graph
    from sbrdf_core.registry import Registry
    from sbrdf_core.runner import Runner
    from sbrdf_core.store import open_artifact
    from sbrdf_lib.scene import load_scene

    store = tmp / kind
    scene = tmp / f"{kind}.yaml"
    scene.write_text(SCENE.format(w=resolution[0], h=resolution[1]))
    text = f"name: roundtrip-{kind}\nstore: {store}\nnodes:\n" + material_nodes(kind, texels) + (
        "  gltf: {kind: Export, plugin: gltf, in: {material: fit}}\n"
        f"  mitsuba: {{kind: Export, plugin: mitsuba, in: {{material: fit}}, params: {{scene: {scene}}}}}\n"
        f"  cpu: {{kind: Render, plugin: cpu, in: {{material: fit}}, params: {{scene: {scene}}}}}\n")
    samples = SAMPLES[kind]  # glTF's GGX fitted to the reflectance samples themselves (source: samples)
    text += (f"  gltf_samples: {{kind: Export, plugin: gltf, in: {{material: fit, samples: {samples}}}, "
             "params: {source: samples}}\n")
    if importlib.util.find_spec("pxr") is not None:
        text += "  usd: {kind: Export, plugin: usd, in: {material: fit}}\n"
    runner = Runner(registry=Registry(extra=["sbrdf_export"]), progress=False)
    t0 = time.perf_counter()
    runner.run(load_graph(text, runner.registry))
    out: dict[str, float | np.ndarray] = {"pipeline_s": time.perf_counter() - t0}  # figures and images
    gltf = open_artifact(f"{store}/gltf")
    rough = gltf.read("maps/roughness")[..., 0]
    err = gltf.read("error")[..., 0]
    out.update(roughness_p50=float(np.median(rough)), roughness_p99=float(np.percentile(rough, 99)),
               conversion_err_p50=float(np.median(err)),
               flagged=float((err > gltf.attrs.get("flag_error", 0.25)).mean()),
               export_gltf_s=gltf.attrs["run"]["wall_s"])
    out.update(usd_roughness_p50=float("nan"), usd_clearcoat_roughness_p50=float("nan"), usd_conv_err_p50=float("nan"))
    if importlib.util.find_spec("pxr"):
        usd = open_artifact(f"{store}/usd")
        out.update(usd_roughness_p50=float(np.median(usd.read("maps/roughness"))),
                   usd_clearcoat_roughness_p50=float(np.median(usd.read("maps/clearcoat_roughness"))),
                   usd_conv_err_p50=float(np.median(usd.read("error"))), export_usd_s=usd.attrs["run"]["wall_s"])
    errs = sample_errors(store, kind)
    fs = open_artifact(f"{store}/gltf_samples")
    out.update(samples_err_p50=errs["gltf"], from_samples_err_p50=errs["gltf_samples"],
               from_samples_roughness_p50=float(np.median(fs.read("maps/roughness"))),
               export_gltf_samples_s=fs.attrs["run"]["wall_s"])
    cpu = open_artifact(f"{store}/cpu").read("image")
    for r in ("gltf", "gltf_samples", "mitsuba"):
        out.update({f"{r}_rel_err": float("nan"), f"{r}_rms": float("nan"), f"{r}_peak_px": float("nan"),
                    f"{r}_peak_ratio": float("nan"), f"{r}_fireflies": -1})
    from sbrdf_export.threejs import available, render_gltf

    why = available()
    if why is None:
        sc = load_scene(str(scene), registry=runner.registry)
        cam = sc.camera
        lights = [{"position": lt.vector, "intensity": lt.power} for lt in sc.lights]
        t0 = time.perf_counter()
        image = render_gltf(str(store / "gltf" / "material.gltf"),
                            {"position": cam.position, "look_at": cam.look_at, "up": cam.up, "fov_deg": cam.fov_deg,
                             "resolution": cam.resolution}, lights, plane_size=2.0, size_mm=gltf.attrs["size_mm"])
        out["threejs_s"] = time.perf_counter() - t0
        out.update({f"gltf_{k}": v for k, v in compare(image, cpu).items()})
        out["images_gltf"] = image
        image = render_gltf(str(store / "gltf_samples" / "material.gltf"),
                            {"position": cam.position, "look_at": cam.look_at, "up": cam.up, "fov_deg": cam.fov_deg,
                             "resolution": cam.resolution}, lights, plane_size=2.0, size_mm=gltf.attrs["size_mm"])
        out.update({f"gltf_samples_{k}": v for k, v in compare(image, cpu).items()})
        out["images_gltf_samples"] = image
    else:
        print(f"three.js render skipped: {why}", file=sys.stderr)
    if importlib.util.find_spec("mitsuba") is not None:
        from sbrdf_export.mitsuba import render

        t0 = time.perf_counter()
        image = render(str(store / "mitsuba" / "scene.xml"))
        out["mitsuba_s"] = time.perf_counter() - t0
        out.update({f"mitsuba_{k}": v for k, v in compare(image, cpu).items()})
        out["images_mitsuba"] = image
    out["images_cpu"] = cpu
    return out


def write_figure(path: Path, results: dict) -> None:
    """Rows glossy, rough: cpu | three.js | Mitsuba, one exposure per row, sRGB."""
    from sbrdf_core.io import linear_to_srgb8, write_png
    from sbrdf_core.nodes.render import display_exposure

    rows = []
    for r in results.values():
        cpu = r["images_cpu"]
        gap = np.zeros((cpu.shape[0], 4, 3))
        row = [cpu, gap, r.get("images_gltf", np.zeros_like(cpu)), gap, r.get("images_mitsuba", np.zeros_like(cpu))]
        rows.append(linear_to_srgb8(np.concatenate(row, 1), display_exposure(cpu)))
    write_png(str(path), np.concatenate(rows, 0))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="32×32 texels, 160×120 pixels")
    ap.add_argument("--figure", type=Path, help="write cpu | three.js | Mitsuba of both materials here")
    ap.add_argument("--images", type=Path, help="save the linear images (cpu, three.js, Mitsuba) as .npz here")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "plugins"))  # before the packages are installed through their entry points
    texels, resolution = (32, (160, 120)) if args.quick else (128, (320, 240))
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for kind in ("glossy", "rough"):
            r = results[kind] = measure(kind, texels, resolution, Path(tmp))
            print(f"{kind} {texels}×{texels} texels, {resolution[0]}×{resolution[1]} px: " + ", ".join(
                f"{k} {v:.4g}" for k, v in r.items() if not k.startswith("images")), flush=True)
    if args.figure:
        write_figure(args.figure, results)
    if args.images:
        np.savez_compressed(args.images, **{f"{kind}_{k[7:]}": v for kind, r in results.items() for k, v in r.items()
                                            if k.startswith("images_")})
    g, r = results["glossy"], results["rough"]
    print(f"interchange_roundtrip: glossy_gltf_rel_err={g['gltf_rel_err']:.4g} "
          f"glossy_mitsuba_rel_err={g['mitsuba_rel_err']:.4g} rough_gltf_rel_err={r['gltf_rel_err']:.4g} "
          f"rough_mitsuba_rel_err={r['mitsuba_rel_err']:.4g} gltf_roughness_p50={g['roughness_p50']:.4g} "
          f"gltf_roughness_p99={g['roughness_p99']:.4g} glossy_gltf_peak_px={g['gltf_peak_px']:.3g} "
          f"glossy_mitsuba_peak_px={g['mitsuba_peak_px']:.3g} rough_gltf_peak_px={r['gltf_peak_px']:.3g} "
          f"rough_mitsuba_peak_px={r['mitsuba_peak_px']:.3g} rough_gltf_peak_ratio={r['gltf_peak_ratio']:.4g} "
          f"rough_mitsuba_peak_ratio={r['mitsuba_peak_ratio']:.4g} glossy_gltf_rms={g['gltf_rms']:.4g} "
          f"glossy_mitsuba_rms={g['mitsuba_rms']:.4g} rough_gltf_rms={r['gltf_rms']:.4g} "
          f"rough_mitsuba_rms={r['mitsuba_rms']:.4g} glossy_fireflies={g['gltf_fireflies']} "
          f"rough_fireflies={r['gltf_fireflies']} glossy_conversion_err={g['conversion_err_p50']:.4g} "
          f"glossy_flagged={g['flagged']:.4g} rough_conversion_err={r['conversion_err_p50']:.4g} "
          f"rough_flagged={r['flagged']:.4g} usd_roughness_p50={g['usd_roughness_p50']:.4g} "
          f"usd_clearcoat_roughness_p50={g['usd_clearcoat_roughness_p50']:.4g} "
          f"usd_conv_err_p50={g['usd_conv_err_p50']:.4g} rough_usd_conv_err_p50={r['usd_conv_err_p50']:.4g} "
          f"glossy_gltf_from_samples_rel_err={g['gltf_samples_rel_err']:.4g} "
          f"rough_gltf_from_samples_rel_err={r['gltf_samples_rel_err']:.4g} "
          f"glossy_gltf_samples_err_p50={g['samples_err_p50']:.4g} "
          f"glossy_gltf_from_samples_samples_err_p50={g['from_samples_err_p50']:.4g} "
          f"rough_gltf_samples_err_p50={r['samples_err_p50']:.4g} "
          f"rough_gltf_from_samples_samples_err_p50={r['from_samples_err_p50']:.4g} "
          f"glossy_gltf_from_samples_roughness_p50={g['from_samples_roughness_p50']:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
