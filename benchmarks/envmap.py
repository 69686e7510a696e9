"""Environment lighting: time per frame against error, per method (seed 000 §6.9, seed 004 §4.4, Table 4.1).

What it measures
----------------
Four cases: a *glossy* (Lafortune lobe C = (−1, −1, 1), n = 120) and a
*rough* (n = 8, ρ_d = 0.15) material, each on a sphere filling most of the
frame and on a plane seen at 45°, lit only by the procedural HDR sky
(``sbrdf_envmap.procedural``, 64×32 lat-long, cube faces 32²).  The ``gl``
renderer draws every method; per method and case:

- ms per frame: the fastest wall time of 5 frames after one warm-up, draw
  calls and glFinish, no read-back (llvmpipe's GL time queries miss its
  deferred rasterisation); the maps are built once, their build time is
  reported separately;
- relative RMS error of the frame against the converged reference, over
  the pixels the object covers: the ``progressive`` method (unbiased QMC,
  MIS of cosine and lobe sampling, unfiltered environment) run for 16
  frames × 256 samples per strategy (4096 per pixel and strategy; its
  own noise, measured by halving, is printed).

Methods: ``prefiltered-discrete`` and ``prefiltered-mip`` (McAllister Eq
6.18), ``sampling`` with 3, 5, …, 19 deterministic samples (Mühlbacher,
Table 4.1's rows), and unbiased sampling at equal time: one progressive
frame whose per-strategy sample count makes it cost about as much as
deterministic sampling with 7 samples.

Sizes: full = 320×240 pixels, reference 16 × 256 samples; ``--quick`` = 128×96, reference 8 × 128
(about a minute).
``--docs`` rewrites the environment-lighting section of
docs/accuracy-vs-time.md and its figure.

Last line: ``envmap: prefiltered_err=... prefiltered_ms=... fis7_err=... fis7_ms=...
mc_equal_time_err=... device=...`` (errors and times are means over the four cases).
"""

from __future__ import annotations

import argparse
import datetime
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from report import machine, replace_section  # noqa: E402

MATERIALS = {
    "glossy": "{model: lafortune, params: {rho_d: 0.02, rho_s_1: 1.0, c_xy_1: -1.0, c_z_1: 1.0, exponent_1: 120}}",
    "rough": "{model: lafortune, params: {rho_d: 0.15, rho_s_1: 0.3, c_xy_1: -1.0, c_z_1: 1.0, exponent_1: 8}}",
}
SHAPES = {
    "sphere": ("{shape: sphere, radius: 0.5, segments: [128, 64], material: m}", "[0.0, -2.0, 0.6]", "[0, 0, 0]"),
    "plane": ("{shape: plane, size: [4, 4], material: m}", "[0.0, -1.2, 1.2]", "[0, 0.3, 0]"),
}
SAMPLES = (3, 5, 7, 9, 11, 13, 15, 17, 19)
OPTIONS = "size: 32, prefiltered_size: 32, diffuse_size: 16"


def scene_text(env: Path, material: str, shape: str, res: tuple[int, int], method: str) -> str:
    obj, eye, look = SHAPES[shape]
    return f"""
camera: {{position: {eye}, look_at: {look}, fov_deg: 40, resolution: [{res[0]}, {res[1]}]}}
materials: {{m: {MATERIALS[material]}}}
objects: [{obj}]
environment: {{file: {env}, options: {{{OPTIONS}, {method}}}}}
antialias: 1  # one sample per pixel: the timings and errors stay those of the lighting methods alone
"""


def draw(text: str, frames: int, timed: int = 5):
    """(last image, fastest wall ms of the timed frames, wall s to build)."""
    from sbrdf_core.registry import default_registry
    from sbrdf_lib.scene import load_scene
    from sbrdf_render import materials as mat
    from sbrdf_render.gl import GLScene

    scene = load_scene(text)
    t0 = time.perf_counter()
    s = GLScene(scene, mat.resolve(scene, None, default_registry()))
    build = time.perf_counter() - t0
    try:
        ms, image = [], None
        for k in range(frames):
            f = s.draw(read=(k == frames - 1))
            ms.append(f.wall_ms)  # llvmpipe's time queries miss deferred rasterisation: wall time incl. glFinish
            image = f.image if f.image is not None else image
        assert image is not None, "the last frame is drawn with read=True"
        return image.astype(np.float64), float(np.min(ms[-timed:])), build  # min: the least disturbed frame
    finally:
        s.release()


def rel_rms(a, ref, mask):
    return float(np.sqrt(((a - ref)[mask] ** 2).mean() / (ref[mask] ** 2).mean()))


def run(env: Path, res: tuple[int, int], ref_samples: int = 256, ref_frames: int = 16) -> dict:
    out = {}
    for material in MATERIALS:
        for shape in SHAPES:
            case = f"{material}-{shape}"
            t0 = time.perf_counter()
            ref, _, _ = draw(scene_text(env, material, shape, res, f"method: progressive, mc_samples: {ref_samples}"),
                             ref_frames, ref_frames)
            half, _, _ = draw(scene_text(env, material, shape, res,
                                         f"method: progressive, mc_samples: {ref_samples // 2}, seed: 9"),
                              ref_frames, ref_frames)
            mask = ref.sum(-1) > 0
            rows = {"reference_noise": rel_rms(half, ref, mask), "reference_s": time.perf_counter() - t0}
            for method in ("prefiltered-discrete", "prefiltered-mip"):
                img, ms, build = draw(scene_text(env, material, shape, res, f"method: {method}"), 6)
                rows[method] = {"ms": ms, "err": rel_rms(img, ref, mask), "build_s": build}
            for k in SAMPLES:
                img, ms, _ = draw(scene_text(env, material, shape, res, f"method: sampling, samples: {k}"), 6)
                rows[f"fis{k}"] = {"ms": ms, "err": rel_rms(img, ref, mask)}
            # unbiased at equal time: the largest per-strategy count whose frame costs no more than fis7's
            best = None
            for n in (1, 2, 3, 4, 6, 8, 12, 16, 24, 32):
                img, ms, _ = draw(scene_text(env, material, shape, res,
                                             f"method: progressive, mc_samples: {n}, seed: 4"), 6)
                if best is None or ms <= rows["fis7"]["ms"] * 1.1:
                    best = {"ms": ms, "err": rel_rms(img, ref, mask), "mc_samples": n}
                if ms > rows["fis7"]["ms"] * 1.1:
                    break
            rows["mc_equal_time"] = best
            out[case] = rows
            print(f"{case}: reference noise {rows['reference_noise']:.4f} ({rows['reference_s']:.1f} s); "
                  + "; ".join(f"{m} {rows[m]['ms']:.1f} ms err {rows[m]['err']:.4f}"
                              for m in ("prefiltered-discrete", "prefiltered-mip", "fis3", "fis7", "fis19",
                                        "mc_equal_time")), flush=True)
    return out


def prefilter_times(env: Path) -> dict:
    """Building the five maps S(·, n) at 32² from the 32² cube (D is S with n = 1): GL pass against NumPy float64."""
    import sbrdf_envmap.cubemap as cubemap
    import sbrdf_envmap.prefilter as prefilter
    from sbrdf_lib.gl import context

    src = cubemap.mip_chain(cubemap.load_environment(str(env), "latlong", 32))[0]
    t0 = time.perf_counter()
    g = dict(zip(prefilter.EXPONENTS, prefilter.prefilter_gl(context(), src, prefilter.EXPONENTS, [32] * 5)))
    t_gl = time.perf_counter() - t0
    t0 = time.perf_counter()
    n = {e: prefilter.prefilter_numpy(src, e, 32) for e in prefilter.EXPONENTS}
    t_np = time.perf_counter() - t0
    diff = max(float(np.abs(g[e] - n[e]).max() / np.abs(n[e]).max()) for e in prefilter.EXPONENTS)
    return {"gl_s": t_gl, "numpy_s": t_np, "max_rel_diff": diff}


def write_docs(results, pre, line, res, device, ref_desc):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    docs = ROOT / "docs"
    (docs / "img").mkdir(parents=True, exist_ok=True)
    date = datetime.date.today().isoformat()
    fig, ax = plt.subplots(figsize=(7.5, 5))
    for i, (case, rows) in enumerate(results.items()):
        c = f"C{i}"
        ax.plot([rows[f"fis{k}"]["ms"] for k in SAMPLES], [rows[f"fis{k}"]["err"] for k in SAMPLES], "o-", color=c,
                ms=3, label=f"{case}: sampling 3…19")
        ax.plot(rows["prefiltered-discrete"]["ms"], rows["prefiltered-discrete"]["err"], "s", color=c, ms=7,
                label=f"{case}: prefiltered discrete")
        ax.plot(rows["prefiltered-mip"]["ms"], rows["prefiltered-mip"]["err"], "D", color=c, mfc="none", ms=7)
        ax.plot(rows["mc_equal_time"]["ms"], rows["mc_equal_time"]["err"], "x", color=c, ms=8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(f"ms per frame, wall, draw + glFinish ({device}, {res[0]}×{res[1]})")
    ax.set_ylabel("relative RMS error vs converged reference")
    ax.set_title("squares: prefiltered discrete, open diamonds: prefiltered MIP, x: unbiased at fis7's time",
                 fontsize=8)
    ax.legend(fontsize=6, ncol=2)
    fig.suptitle(f"{machine()}, {date}", fontsize=7)
    fig.tight_layout()
    fig.savefig(docs / "img" / "envmap-error-time.png", dpi=120)
    cases = list(results)
    head = "| method | " + " | ".join(f"{c} ms | {c} err" for c in cases) + " |"
    table = [head, "|---|" + "---:|" * (2 * len(cases))]
    labels = [("prefiltered-discrete", "prefiltered, discrete n"), ("prefiltered-mip", "prefiltered, MIP")]
    labels += [(f"fis{k}", f"sampling, {k} samples") for k in SAMPLES] + [("mc_equal_time", "unbiased, equal time")]
    for key, label in labels:
        table.append(f"| {label} | " + " | ".join(f"{results[c][key]['ms']:.1f} | {results[c][key]['err']:.4f}"
                                                  for c in cases) + " |")
    mc = ", ".join(f"{c}: {results[c]['mc_equal_time']['mc_samples']}" for c in cases)
    pre_errs = [results[c]["prefiltered-discrete"]["err"] for c in cases]
    lo_pre, hi_pre = min(pre_errs), max(pre_errs)
    mc_errs = [results[c]["mc_equal_time"]["err"] for c in cases]
    mc_lo, mc_hi = min(mc_errs), max(mc_errs)

    def first_better(c):
        k = [k for k in SAMPLES if results[c][f"fis{k}"]["err"] < results[c]["prefiltered-discrete"]["err"]]
        return f"{c}: {k[0]}" if k else f"{c}: never up to 19"

    beats = "; ".join(first_better(c) for c in cases)
    noise = ", ".join(f"{c}: {results[c]['reference_noise']:.4f}" for c in cases)
    section = "\n".join([
        "<!-- environment-lighting:begin (generated by benchmarks/envmap.py --docs; do not edit by hand) -->",
        "## Environment lighting",
        "",
        "Cases: a glossy (Lafortune n = 120) and a rough (n = 8) material on a sphere and on a plane, lit only by "
        "the procedural 64×32 HDR sky (cube faces 32²), drawn by the `gl` renderer "
        f"({res[0]}×{res[1]}). Error: relative RMS over the object's pixels against the converged unbiased "
        f"reference (`progressive`, {ref_desc} samples per strategy; its noise, from a second run with half "
        f"the samples: {noise}). Time: the fastest of 5 frames, wall time (draw + glFinish; the minimum is the frame least disturbed by the other processes). Methods: "
        "[environment-lighting.md](environment-lighting.md). Table 4.1's layout: one row per sample count.",
        f"Machine: {machine()}; device {device}. "
        f"Date: {date}.",
        "",
        "![error against time per frame](img/envmap-error-time.png)",
        "",
        *table,
        "",
        f"Unbiased at equal time: per-strategy samples per pixel that fit in fis7's frame time: {mc}.",
        "Building the five prefiltered maps (S for n = 1…256, 32² each, from the 32² cube; D is S with n = 1): "
        f"GL pass "
        f"{pre['gl_s']:.2f} s, NumPy float64 reference {pre['numpy_s']:.2f} s, largest relative difference "
        f"{pre['max_rel_diff']:.1e}.",
        "",
        "Headline (means over the four cases):",
        "",
        f"    {line}",
        "",
        f"Reading it: prefiltering's error is {lo_pre:.0%}–{hi_pre:.0%} in every case at a cost that does not "
        "depend on the lobe: Eq 6.18 takes N·ω_i out of the integral at the lobe peak, the exponent is blended "
        "between maps 4× apart, and the maps are 32² per face. Deterministic sampling's cost grows about "
        "linearly with the sample count (Table 4.1's shape; single rows jump where other processes took the "
        "CPU) and its error falls with the count; it is more accurate than prefiltering from "
        f"{beats} samples on. Unbiased sampling in the same time as 7 deterministic samples has "
        f"{mc_lo:.0%}–{mc_hi:.0%} error, all of it noise: the deterministic pattern trades that for a "
        "bias that does not flicker.",
        "<!-- environment-lighting:end -->",
        "",
    ])
    replace_section("environment-lighting", section)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--quick", action="store_true", help="small images, about a minute")
    ap.add_argument("--docs", action="store_true", help="rewrite the environment-lighting section of "
                                                        "docs/accuracy-vs-time.md")
    args = ap.parse_args(argv)
    res = (128, 96) if args.quick else (320, 240)
    import tempfile

    from sbrdf_core.io import write_exr
    from sbrdf_envmap.procedural import sky
    from sbrdf_lib.gl import device_name

    device = device_name().split()[0].lower()
    with tempfile.TemporaryDirectory(prefix="sbrdf-envmap-") as d:
        env = Path(d) / "sky.exr"
        write_exr(str(env), sky())
        pre = prefilter_times(env)
        print(f"prefilter 5 maps 32²: gl {pre['gl_s']:.2f} s, numpy {pre['numpy_s']:.2f} s, "
              f"max rel diff {pre['max_rel_diff']:.1e}", flush=True)
        results = run(env, res, *((128, 8) if args.quick else (256, 16)))
    mean = lambda key, f: float(np.mean([r[key][f] for r in results.values()]))  # noqa: E731
    line = (f"envmap: prefiltered_err={mean('prefiltered-discrete', 'err'):.4f} "
            f"prefiltered_ms={mean('prefiltered-discrete', 'ms'):.2f} fis7_err={mean('fis7', 'err'):.4f} "
            f"fis7_ms={mean('fis7', 'ms'):.2f} mc_equal_time_err={mean('mc_equal_time', 'err'):.4f} device={device}")
    if args.docs:
        write_docs(results, pre, line, res, device, "8 frames × 128" if args.quick else "16 frames × 256")
    print(line)


if __name__ == "__main__":
    main()
