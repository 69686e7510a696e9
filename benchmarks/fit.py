"""Fitting: what each fitter's accuracy costs in time (issue 3; seed 000 Table 3.4).

What it measures
----------------
A ``SampleModel`` node draws a 2-lobe Lafortune SBRDF (procedural maps over
the model's typical ranges) at 400 direction pairs per texel with Gaussian
noise σ = 0.01 sr⁻¹, into a SampledReflectance on disk.  Then, each as a Fit
node run by the real Runner (threads scheduler, all cores), timed by the node's
wall clock:

- ``ls``:  McAllister's single-lobe line search (``line-search``);
- ``lm1``: batched Levenberg–Marquardt, 1 lobe (``lm``, model lafortune);
- ``lm2``: the same with 2 lobes.

``*_ms_per_texel`` is node wall time / texels.  ``lm2_rms`` (and the others in
the table) is the mean over texels of the per-texel RMS residual, sr⁻¹, RGB
pooled (seed 000 §4.4).

The scientist's baseline: the same 2-lobe fit written as a per-texel loop over
``scipy.optimize.least_squares`` (default trust-region solver, 2-point numeric
Jacobian, the model's raw parametrisation and bounds, the same starting point
as ``lm``) on a subset of texels, one core; its time per texel extrapolates to
the whole grid.  ``speedup_vs_scipy`` = scipy ms per texel / lm2 ms per texel;
``rms_ratio_vs_scipy`` = lm2 mean RMS / scipy mean RMS on the same subset.

Then a sweep on a smaller grid gives the accuracy-vs-time table and plot of
``docs/accuracy-vs-time.md`` (fitters × lobes × iteration cap × samples per
texel); ``--docs`` rewrites that section and its figure.

Sizes: full = 256×256 texels × 400 pairs (65 536 texels; scipy on 256 of
them), sweep on 64×64; ``--quick`` = 64×64 texels (scipy on 48), sweep on
32×32 — about a minute on 2 cores.

Last line: ``fit: texels=... ls_ms_per_texel=... lm1_ms_per_texel=...
lm2_ms_per_texel=... speedup_vs_scipy=... rms_ratio_vs_scipy=... lm2_rms=...``
"""

from __future__ import annotations

import argparse
import datetime
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from report import machine, replace_section

ROOT = Path(__file__).resolve().parent.parent
NOISE = 0.01
TWO_LOBES = {"lobes": 2}


def graph_text(texels, poses, fits: dict[str, dict], noise=NOISE, seed=0) -> str:
    sample = {"model": "lafortune", "model_params": TWO_LOBES, "texels": list(texels), "poses": poses,
              "noise": noise, "seed": seed, "directions": "random", "max_theta_deg": 80.0}
    lines = ["name: fit-benchmark", "store: ./store", "nodes:",
             f"  samples: {{kind: SampleModel, params: {json.dumps(sample)}}}"]
    for name, spec in fits.items():
        lines.append(f"  {name}: {{kind: Fit, plugin: {spec['plugin']}, in: {{samples: samples}}, "
                     f"params: {json.dumps(spec.get('params', {}))}}}")
    return "\n".join(lines) + "\n"


FITS = {
    "ls": {"plugin": "line-search"},
    "lm1": {"plugin": "lm", "params": {"model": "lafortune", "model_params": {"lobes": 1}}},
    "lm2": {"plugin": "lm", "params": {"model": "lafortune", "model_params": TWO_LOBES}},
}


def run(workdir: Path, texels, poses, fits) -> dict:
    from sbrdf_core.graph import load_graph
    from sbrdf_core.registry import Registry
    from sbrdf_core.runner import Runner
    from sbrdf_core.store import open_artifact

    path = workdir / "graph.yaml"
    path.write_text(graph_text(texels, poses, fits))
    reg = Registry()
    graph = load_graph(path, reg)
    report = Runner(reg, progress=False).run(graph)
    out = {}
    for name in fits:
        art = open_artifact(graph.url(name))
        out[name] = {"wall_s": report[name].wall_s, "rms": art.read("rms").astype(np.float64),
                     "summary": art.attrs["summary"], "url": graph.url(name)}
    out["samples"] = graph.url("samples")
    return out


def scipy_baseline(samples_url: str, subset: int, seed: int = 0) -> dict:
    """The 2-lobe fit as a per-texel loop over scipy.optimize.least_squares, on ``subset`` texels."""
    from scipy.optimize import least_squares

    from sbrdf_core.geometry import tile_directions
    from sbrdf_core.registry import Registry
    from sbrdf_core.store import open_artifact

    art = open_artifact(samples_url)
    U, V = art.attrs["texels"]
    rng = np.random.default_rng(seed)
    picks = rng.choice(U * V, subset, replace=False)
    model = Registry().create("brdf-model", "lafortune", TWO_LOBES)
    lo, hi = model.bounds()
    light, camera = art.read("light_pos"), art.read("camera_pos")
    f_all, v_all = art.array("f_r"), art.array("valid")
    rms, starts, seconds = [], [], 0.0
    for flat in picks:
        v, u = divmod(int(flat), U)
        f = np.asarray(f_all[v, u].compute(), np.float64)[None]
        ok = np.asarray(v_all[v, u].compute())[None]
        wi, _, wo = tile_directions((U, V), tuple(art.attrs["size_mm"]), (v, v + 1), (u, u + 1), light, camera)
        x0 = np.clip(model.pack(model.initial_guess(f, ok, wi, wo))[0], lo, hi)
        starts.append(x0)

        def residual(x):
            return ((model.eval(model.unpack(x[None]), wi, wo) - f) * ok[..., None]).ravel()

        t0 = time.perf_counter()
        sol = least_squares(residual, x0, bounds=(lo, hi))
        seconds += time.perf_counter() - t0
        r = residual(sol.x)
        rms.append(np.sqrt(np.sum(r * r) / (3 * ok.sum())))
    return {"picks": picks, "rms": np.array(rms), "ms_per_texel": 1e3 * seconds / subset}


SWEEP = [  # (label, plugin, params) — iteration caps only where the fitter iterates
    ("line search", "line-search", {}),
    ("McAllister LM, 1 lobe", "mcallister", {"model_params": {"lobes": 1}}),
    ("McAllister LM, 2 lobes", "mcallister", {"model_params": TWO_LOBES}),
] + [
    (f"LM, {lobes} lobe{'s' if lobes > 1 else ''}, ≤{its} it", "lm",
     {"model": "lafortune", "model_params": {"lobes": lobes}, "iterations": its})
    for lobes in (1, 2) for its in (5, 15, 50)
]


def sweep(workdir: Path, texels, sample_counts) -> list[dict]:
    rows = []
    for poses in sample_counts:
        fits = {f"s{k}": {"plugin": plugin, "params": params} for k, (_, plugin, params) in enumerate(SWEEP)}
        sub = workdir / f"sweep-{poses}"
        sub.mkdir()
        res = run(sub, texels, poses, fits)
        n = texels[0] * texels[1]
        for k, (label, plugin, params) in enumerate(SWEEP):
            r = res[f"s{k}"]
            rows.append({"fitter": label, "samples": poses, "ms_per_texel": 1e3 * r["wall_s"] / n,
                         "rms_mean": float(r["rms"].mean()), "rms_max": float(r["rms"].max())})
        shutil.rmtree(sub, ignore_errors=True)
    return rows


def write_docs(rows, main_line, texels, sweep_texels, scipy_subset):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    docs = ROOT / "docs"
    (docs / "img").mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for label in dict.fromkeys(r["fitter"] for r in rows):
        pts = sorted((r["ms_per_texel"], r["rms_mean"], r["samples"]) for r in rows if r["fitter"] == label)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label)
        for p in pts:
            ax.annotate(str(p[2]), (p[0], p[1]), fontsize=6, xytext=(2, 2), textcoords="offset points")
    ax.axhline(NOISE, color="grey", lw=0.8, ls="--", label=f"noise σ = {NOISE} sr⁻¹")
    ax.set_xscale("log"), ax.set_yscale("log")
    ax.set_xlabel("wall time per texel, ms (2-core run, all texels in parallel)")
    ax.set_ylabel("mean per-texel RMS, sr⁻¹")
    date = datetime.date.today().isoformat()
    ax.set_title(f"Fitting a 2-lobe Lafortune SBRDF, {sweep_texels[0]}×{sweep_texels[1]} texels "
                 f"(labels: samples/texel)\n{machine()}, {date}", fontsize=8)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(docs / "img" / "fit-accuracy-vs-time.png", dpi=120)
    table = ["| fitter | samples/texel | ms/texel | mean RMS (sr⁻¹) | max RMS (sr⁻¹) |", "|---|---:|---:|---:|---:|"]
    table += [f"| {r['fitter']} | {r['samples']} | {r['ms_per_texel']:.3f} | {r['rms_mean']:.5f} | {r['rms_max']:.5f} |"
              for r in rows]
    section = "\n".join([
        "<!-- fit:begin (generated by benchmarks/fit.py --docs; do not edit by hand) -->",
        "## Fitting",
        "",
        f"Data: a 2-lobe Lafortune SBRDF sampled at random direction pairs (θ ≤ 80°) with Gaussian noise "
        f"σ = {NOISE} sr⁻¹ (`SampleModel`), fitted by each fitter as a `Fit` node (Runner, threads scheduler). "
        "Time is node wall time divided by texels; RMS is the per-texel residual RMS (RGB pooled), averaged and "
        "maximised over texels.",
        f"Machine: {machine()}. Date: {date}. Sweep grid: {sweep_texels[0]}×{sweep_texels[1]} texels.",
        "",
        "![RMS against time per texel](img/fit-accuracy-vs-time.png)",
        "",
        *table,
        "",
        f"Headline run ({texels[0]}×{texels[1]} texels × 400 samples; scipy baseline on {scipy_subset} texels):",
        "",
        f"    {main_line}",
        "",
        "Reading it: the line search is the cheapest per iteration and, at this noise, by far the least accurate "
        "(its n-th root amplifies noise; seed 000 §4.3.2 reports the same failure above 10⁻⁴ sr⁻¹). One lobe cannot "
        "reach the noise floor on 2-lobe data; two lobes do. A low iteration cap trades RMS for time, and more "
        "samples per texel cost time almost linearly.",
        "<!-- fit:end -->",
        "",
    ])
    replace_section("fit", section)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="64x64 texels, sweep on 32x32 (about a minute)")
    ap.add_argument("--docs", action="store_true", help="rewrite the Fitting section of docs/accuracy-vs-time.md")
    ap.add_argument("--no-sweep", action="store_true", help="only the headline figures")
    args = ap.parse_args()
    texels = (64, 64) if args.quick else (256, 256)
    sweep_texels = (32, 32) if args.quick else (64, 64)
    subset = 48 if args.quick else 256
    n = texels[0] * texels[1]
    workdir = Path(tempfile.mkdtemp(prefix="sbrdf-fit-bench-"))
    try:
        warm = workdir / "warm"  # import, JIT-compile and cache the kernels off the clock
        warm.mkdir()
        run(warm, (8, 8), 50, FITS)
        main_dir = workdir / "main"
        main_dir.mkdir()
        res = run(main_dir, texels, 400, FITS)
        base = scipy_baseline(res["samples"], subset)
        lm2_subset = res["lm2"]["rms"].reshape(-1)[base["picks"]]
        ms = {k: 1e3 * res[k]["wall_s"] / n for k in FITS}
        for k in FITS:
            print(f"{k:>4}: {res[k]['wall_s']:8.2f} s wall, {ms[k]:.4f} ms/texel, mean RMS {res[k]['rms'].mean():.5f}, "
                  f"max {res[k]['rms'].max():.5f}, flagged {res[k]['summary'].get('texels_flagged', {})}")
        print(f"scipy least_squares loop: {base['ms_per_texel']:.2f} ms/texel on {subset} texels "
              f"(all {n}: {base['ms_per_texel'] * n / 1e3:.0f} s extrapolated), mean RMS {base['rms'].mean():.5f} "
              f"vs lm2 {lm2_subset.mean():.5f} on the same texels")
        line = (f"fit: texels={n} ls_ms_per_texel={ms['ls']:.4f} lm1_ms_per_texel={ms['lm1']:.4f} "
                f"lm2_ms_per_texel={ms['lm2']:.4f} speedup_vs_scipy={base['ms_per_texel'] / ms['lm2']:.1f} "
                f"rms_ratio_vs_scipy={lm2_subset.mean() / base['rms'].mean():.4f} lm2_rms={res['lm2']['rms'].mean():.5f}")
        shutil.rmtree(main_dir, ignore_errors=True)
        if not args.no_sweep:
            rows = sweep(workdir, sweep_texels, (100, 200, 400))
            for r in rows:
                print(f"  {r['fitter']:<28} S={r['samples']:<4} {r['ms_per_texel']:8.4f} ms/texel  "
                      f"RMS {r['rms_mean']:.5f} (max {r['rms_max']:.5f})")
            if args.docs:
                write_docs(rows, line, texels, sweep_texels, subset)
        print(line)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
