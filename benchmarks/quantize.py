"""Quantizing and MIP-mapping a fitted SBRDF: what precision and filtering cost (seed 000 §6.5, Ch 5).

What it measures
----------------
A ``SampleModel`` node draws a 2-lobe Lafortune SBRDF (procedural maps over
the model's typical ranges) at random direction pairs with Gaussian noise
σ = 0.01 sr⁻¹; ``lm`` fits 2 lobes to it.  Each texture layout is then a
Quantize node (Runner, threads scheduler) given the fit and its samples:

- ``float32``, ``float16``: ``float-exr`` (EXR + JSON written too);
- ``fixed16``: 16-bit fixed point, log exponents;
- ``linear8``: the plain per-channel 8-bit map (baseline);
- ``hw8``: McAllister's hardware layout, ``rescale: max``, C over −1..1 (the
  headline), plus the other rescale strategy and the −2..2 mapping;
- ``palette``: 256 BRDFs clustered in sampled-BRDF space (1 byte per texel
  plus the shared palette).

Per layout: the RMS it added (sr⁻¹) over a uniform direction set (Fibonacci
pairs, θ ≤ 85°: includes grazing pairs never measured), pooled over texels and
as the median texel, the pooled RMS over each texel's own valid sampled
directions, bytes per texel, node time.  ``*_rms`` in the last line are the
*median texel* values over the uniform set: a fitted SBRDF has a few texels
whose lobes explode at grazing (|C| > 1 with n in the thousands, values
capped at e^60 by the model), where any change of precision gives an
astronomically large absolute difference, and pooled numbers measure only
those texels.

MIP level 1 of a ``mip`` × ``mip`` corner of the fit, three ways, each against
the BRDF-space average of the 2×2 children (uniform pairs):
``lerp`` (average the parameters), ``refit`` (sample–blend–refit, §5.2),
``samples`` (refit to the 2×2-downsampled SampledReflectance).  Error is the
per-coarse-texel RMS, sr⁻¹, against that average: ``*_mip_err`` is its
*median* over coarse texels (the mean is reported too; a few texels whose fit
left a dead lobe at the parameter bounds, ρ_s ≈ 0 with |C| = 10 and
n = 2·10⁴, make the lerp's mean astronomically large, since averaging such a
lobe's parameters with a live neighbour's revives it); time is wall time.

Sizes: full = 256×256 texels × 300 pairs, MIP on 128×128; ``--quick`` =
48×48 × 150 pairs, MIP on 32×32 (about a minute on 2 cores).  ``--docs``
rewrites the quantize section of docs/accuracy-vs-time.md and its figure.

Last line: ``quantize: float16_rms=... fixed16_rms=... hw8_rms=...
hw8_bytes_per_texel=... refit_mip_err=... lerp_mip_err=...``
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from report import machine, replace_section  # noqa: E402

NOISE = 0.01
TWO_LOBES = {"lobes": 2}

LAYOUTS = {  # node -> (label, plugin, params)
    "float32": ("float-exr float32", "float-exr", {"dtype": "float32"}),
    "float16": ("float-exr half", "float-exr", {"dtype": "float16"}),
    "fixed16": ("fixed16", "fixed16", {}),
    "linear8": ("linear uint8", "linear", {"dtype": "uint8"}),
    "hw8": ("mcallister8 max, C ±1", "mcallister8", {"rescale": "max", "c_range": 1.0}),
    "hw8_c2": ("mcallister8 max, C ±2", "mcallister8", {"rescale": "max", "c_range": 2.0}),
    "hw8_bal": ("mcallister8 balanced, C ±1", "mcallister8", {"rescale": "balanced", "c_range": 1.0}),
    "hw8_bal_c2": ("mcallister8 balanced, C ±2", "mcallister8", {"rescale": "balanced", "c_range": 2.0}),
    "palette": ("palette 256", "palette", {"k": 256, "directions": 8}),
}


def graph_text(texels, poses) -> str:
    sample = {"model": "lafortune", "model_params": TWO_LOBES, "texels": list(texels), "poses": poses,
              "noise": NOISE, "seed": 0, "directions": "random", "max_theta_deg": 80.0}
    fit = {"model": "lafortune", "model_params": TWO_LOBES}
    lines = ["name: quantize-benchmark", "store: ./store", "nodes:",
             f"  samples: {{kind: SampleModel, params: {json.dumps(sample)}}}",
             f"  fit: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {json.dumps(fit)}}}"]
    for node, (_, plugin, params) in LAYOUTS.items():
        lines.append(f"  {node}: {{kind: Quantize, plugin: {plugin}, in: {{params: fit, samples: samples}}, "
                     f"params: {json.dumps(params)}}}")
    return "\n".join(lines) + "\n"


def run_layouts(workdir: Path, texels, poses):
    from sbrdf_core.graph import load_graph
    from sbrdf_core.registry import Registry
    from sbrdf_core.runner import Runner
    from sbrdf_core.store import open_artifact

    path = workdir / "graph.yaml"
    path.write_text(graph_text(texels, poses))
    reg = Registry()
    graph = load_graph(path, reg)
    report = Runner(reg, progress=False).run(graph)
    rows = []
    for node, (label, _, _) in LAYOUTS.items():
        a = open_artifact(graph.url(node))
        rows.append({"node": node, "layout": label, "rms": a.attrs["added_rms"], "rms_own": a.attrs["added_rms_own"],
                     "median": float(np.median(a.read("error"))),
                     "max": a.attrs["added_max"], "bytes": a.attrs["bytes_per_texel"], "wall_s": report[node].wall_s,
                     "palette_bytes": a.attrs.get("palette_bytes", 0)})
    return rows, graph.url("fit"), graph.url("samples"), report["fit"].wall_s


def run_mips(fit_url, samples_url, size):
    from sbrdf_core.registry import Registry
    from sbrdf_core.store import open_artifact
    from sbrdf_quantizers import interpolate as ip

    reg = Registry()
    model = reg.create("brdf-model", "lafortune", TWO_LOBES)
    fit = open_artifact(fit_url)
    params = {k.split("/", 1)[1]: fit.read(k)[:size, :size].astype(np.float64)
              for k in fit.names() if k.startswith("params/")}
    samples = open_artifact(samples_url)
    U, V = samples.attrs["texels"]
    f_r = samples.array("f_r")[:size, :size].compute().astype(np.float64)
    valid = samples.array("valid")[:size, :size].compute()
    # the corner's own texel grid: size_mm scaled so texel centres stay where they were
    size_mm = samples.attrs["size_mm"]
    light, camera = samples.read("light_pos"), samples.read("camera_pos")
    shift = np.array([(size - U) / 2 * size_mm[0] / U, (size - V) / 2 * size_mm[1] / V, 0.0])
    corner_mm = (size_mm[0] * size / U, size_mm[1] * size / V)

    ref = ip.brdf_average(model, params)
    out = {}
    t0 = time.perf_counter()
    lerp = ip.mip_lerp(params)
    out["lerp"] = (ip.mip_error(model, lerp, ref), time.perf_counter() - t0)
    t0 = time.perf_counter()
    refit = ip.mip_refit(model, params)
    out["refit"] = (ip.mip_error(model, refit, ref), time.perf_counter() - t0)
    t0 = time.perf_counter()
    # texel centres of the corner relative to its own centre = sample frame + shift
    per_level = ip.mip_refit_samples(model, f_r, valid, (size, size), corner_mm, light - shift, camera - shift,
                                     starts_from=lerp)
    out["samples"] = (ip.mip_error(model, per_level, ref), time.perf_counter() - t0)
    return {k: {"err": float(np.median(e)), "err_mean": float(e.mean()), "err_max": float(e.max()), "s": s}
            for k, (e, s) in out.items()}


def write_docs(rows, mips, main_line, texels, poses, mip_size):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    docs = ROOT / "docs"
    (docs / "img").mkdir(parents=True, exist_ok=True)
    date = datetime.date.today().isoformat()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.4))
    for r in rows:
        y = max(r["median"], 1e-9)
        a1.plot(r["bytes"], y, "o")
        a1.annotate(r["layout"], (r["bytes"], y), fontsize=6, xytext=(3, 2), textcoords="offset points")
    a1.set_xscale("log"), a1.set_yscale("log")
    a1.set_xlabel("bytes per texel"), a1.set_ylabel("added RMS, uniform pairs, median texel, sr⁻¹\n(float32: 0, drawn at 1e-9)")
    a1.axhline(NOISE, color="grey", lw=0.8, ls="--", label=f"capture noise σ = {NOISE}")
    a1.legend(fontsize=7)
    for k, m in mips.items():
        a2.plot(max(m["s"], 1e-4), m["err"], "s", label=f"{k} (median texel)")
    a2.set_xscale("log"), a2.set_yscale("log")
    a2.set_xlabel("wall time, s"), a2.set_ylabel("median texel RMS vs BRDF-space average, sr⁻¹")
    a2.legend(fontsize=7)
    fig.suptitle(f"2-lobe Lafortune SBRDF {texels[0]}×{texels[1]} texels, {poses} samples/texel; "
                 f"MIP on {mip_size}×{mip_size}\n{machine()}, {date}", fontsize=8)
    fig.tight_layout()
    fig.savefig(docs / "img" / "quantize-accuracy.png", dpi=120)
    table = ["| layout | bytes/texel | added RMS, uniform (sr⁻¹) | added RMS, own samples (sr⁻¹) | median texel (sr⁻¹) "
             "| max texel (sr⁻¹) | node s |", "|---|---:|---:|---:|---:|---:|---:|"]
    table += [f"| {r['layout']} | {r['bytes']} | {r['rms']:.3g} | {r['rms_own']:.3g} | {r['median']:.3g} | {r['max']:.3g} "
              f"| {r['wall_s']:.2f} |" for r in rows]
    mtable = ["| MIP method | median texel RMS vs BRDF average (sr⁻¹) | mean (sr⁻¹) | max (sr⁻¹) | time (s) |",
              "|---|---:|---:|---:|---:|"]
    mtable += [f"| {k} | {m['err']:.4g} | {m['err_mean']:.4g} | {m['err_max']:.4g} | {m['s']:.2f} |" for k, m in mips.items()]
    section = "\n".join([
        "<!-- quantize:begin (generated by benchmarks/quantize.py --docs; do not edit by hand) -->",
        "## Quantizing and MIP levels",
        "",
        f"Data: a 2-lobe Lafortune SBRDF, {texels[0]}×{texels[1]} texels × {poses} random direction pairs, noise "
        f"σ = {NOISE} sr⁻¹ (`SampleModel`), fitted by `lm` (2 lobes), then each layout as a `Quantize` node given "
        "the fit and its samples. Added RMS per texel over uniform Fibonacci pairs (θ ≤ 85°, grazing included), "
        "pooled over texels and at the median texel, and pooled over each texel's own valid samples. "
        "Layouts: [textures.md](textures.md).",
        f"Machine: {machine()}. Date: {date}.",
        "",
        "![added error against bytes per texel, and MIP error against time](img/quantize-accuracy.png)",
        "",
        *table,
        "",
        f"MIP level 1 of the {mip_size}×{mip_size} corner, each method against the BRDF-space average of the "
        "2×2 children (seed 000 Ch 5):",
        "",
        *mtable,
        "",
        "Headline:",
        "",
        f"    {main_line}",
        "",
        "Reading it: the headline numbers are median texels; the pooled columns are dominated by a few texels "
        "whose fitted lobes explode at grazing (|C| > 1 with n in the thousands, or a dead lobe left at the "
        "parameter bounds: ρ_s ≈ 0, |C| = 10, n = 2·10⁴), where the model's values reach its e^60 cap and any "
        "change of precision is an astronomically large absolute difference; over the texels' own (measured) "
        "directions those texels behave. "
        "float32 adds nothing; half float and 16-bit fixed point (log-encoded magnitudes and exponents) add far "
        "less than the capture noise. The 8-bit hardware layout with C over −1..1 adds error of the order of a "
        "tenth of the noise at the median texel: C clamps at ±1, exponents above 255 clamp, ρ_d has 1/255 sr⁻¹ "
        "steps. The −2..2 mapping is not a free fix on fitted data: for a dead lobe the rescale sets ρ_s to 1, C "
        "clamps at ±2 instead of ±1 and n at 255, and x > 1 with n = 255 revives the lobe at grazing. The "
        "shading-time artifacts of the hardware layout (x clamped to 1, 8-bit table lookups) come on top and are "
        "shown by the tests, not by these numbers, which evaluate the decoded parameters with float `pow`. "
        "For MIP levels, averaging parameters is cheapest and worst (and revives dead lobes: see its mean); "
        "refitting to the averaged sampled BRDFs is the accurate one at the median; refitting to the downsampled "
        "measurements never sees the unmeasured grazing pairs where refits of exploding lobes go wrong, so its "
        "mean and max are the best.",
        "<!-- quantize:end -->",
        "",
    ])
    replace_section("quantize", section)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, about a minute")
    ap.add_argument("--docs", action="store_true", help="rewrite the quantize section of docs/accuracy-vs-time.md")
    args = ap.parse_args(argv)
    texels, poses, mip_size = ((48, 48), 150, 32) if args.quick else ((256, 256), 300, 128)
    with tempfile.TemporaryDirectory(prefix="sbrdf-quantize-") as d:
        work = Path(d)
        rows, fit_url, samples_url, fit_s = run_layouts(work, texels, poses)
        print(f"fit: {texels[0]}×{texels[1]} texels × {poses} pairs in {fit_s:.1f} s", flush=True)
        for r in rows:
            print(f"{r['layout']:<28} {r['bytes']:>4} B/texel  added rms {r['rms']:.3g} (own {r['rms_own']:.3g}) "
                  f"median {r['median']:.3g} max {r['max']:.3g}  {r['wall_s']:.2f} s", flush=True)
        mips = run_mips(fit_url, samples_url, mip_size)
        for k, m in mips.items():
            print(f"mip {k:<8} median err {m['err']:.4g} mean {m['err_mean']:.4g} max {m['err_max']:.4g} sr^-1  "
                  f"{m['s']:.2f} s", flush=True)
    by = {r["node"]: r for r in rows}
    line = (f"quantize: float16_rms={by['float16']['median']:.3g} fixed16_rms={by['fixed16']['median']:.3g} "
            f"hw8_rms={by['hw8']['median']:.3g} hw8_bytes_per_texel={by['hw8']['bytes']} "
            f"refit_mip_err={mips['refit']['err']:.4g} lerp_mip_err={mips['lerp']['err']:.4g}")
    if args.docs:
        write_docs(rows, mips, line, texels, poses, mip_size)
    print(line)


if __name__ == "__main__":
    main()
