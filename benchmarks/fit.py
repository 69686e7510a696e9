"""Every built-in model fitted on a virtual capture: CPU per texel, convergence, training and held-out error.

What it measures
----------------
One material that none of the fitted models contains: anisotropic Lafortune
with three lobes and a per-texel β, in three vertical bands of the sample
(plastic, metal, brushed metal), whose forward lobes **rise toward grazing**
(|C_xy| > C_z) as Fresnel makes real ones do, while its directional albedo
stays under 0.8 everywhere (a physical material: the Fit node's energy bound
does not move its fits).  It is photographed by the
project's ``virtual-camera`` (falloff, blur, motor error, shot noise; one
linear exposure per pose, :data:`FULL` poses on an orbit), and the photographs
go through the path a user's scan takes: ``folder`` Capture → ``aruco``
Register → Reflectance → ``Fit`` (``lm``, every option the default; only
``model`` and ``model_params`` set) for each model of :data:`FITS`.

Per model, each Fit node run alone by the graph runner (one dask thread, so
process CPU time is that of one core's work; numba's threads inside):

- ``X_ms``: process CPU time of the Fit node's run / texels, ms;
- ``X_conv``: fraction of texels with samples that the fitter converged
  (no ``not converged`` flag);
- ``X_train``, ``X_held``: the node's mean training RMS and mean held-out RMS
  (the node keeps 10 % of each texel's samples from the fitter; sr⁻¹);
- ``X_err``: median relative luminance error against the truth at direction
  pairs no capture contains (``benchmarks/fidelity.py``'s scoring pairs).

``nested_worse``: texels whose 2-lobe Lafortune training RMS exceeds their
1-lobe one by more than one part in 10⁶, the 2-lobe node given the 1-lobe
maps as its ``start`` (as docs/fitting.md tells a user to);
``nested_alone``: the same for a 2-lobe node fitted alone.  ``converged_min``: the lowest
``X_conv``.  ``scaling_2``: the 2-lobe Fit node's wall time with one dask
thread over that with two (median of pairs run in alternating order).  At
``--quick`` size the node is one task (a 32² tile), so there ``scaling_2`` is
about 1 and says nothing; at full size the tile is fitted in strips of rows
sized by memory (:func:`sbrdf_core.nodes.fit.fit_block`), whose balance over
two threads bounds it.

Sizes: full = 64×64 texels, 160 poses, 640×480 photographs; ``--quick`` =
32×32 texels, 150 poses, 400×300 (about a minute once kernels are compiled).
Kernels are compiled (or loaded from the cache) off the clock first.

Last line::

    fit: laf1_ms=... laf2_ms=... ward_ms=... ct_ms=... ggxa_ms=... converged_min=... nested_worse=...
         scaling_2=... nested_alone=... (then every model's X_ms, X_conv, X_train, X_held, X_err)
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fidelity  # noqa: E402  (its truth writer, virtual capture and scoring)

FULL = {"texels": 64, "width": 640, "height": 480, "focal": 900.0, "orbit": 160, "pairs": 3}
QUICK = {"texels": 32, "width": 400, "height": 300, "focal": 560.0, "orbit": 150, "pairs": 1}

#: fit name -> (model, model_params)
FITS: dict[str, tuple[str, dict]] = {
    "lambert": ("lambert", {}),
    "phong": ("phong", {}),
    "laf1": ("lafortune", {"lobes": 1}),
    "laf2": ("lafortune", {"lobes": 2}),
    "ward": ("ward", {}),
    "ct": ("cook-torrance", {"distribution": "ggx"}),
    "ggxa": ("ggx-anisotropic", {}),
}
TRUTH = ("lafortune", {"lobes": 3, "anisotropic": True, "beta": True})
#: fit name -> the fit it starts from (the Fit node's ``start`` input)
STARTS = {"laf2": "laf1"}


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def truth_maps(n: int) -> dict[str, np.ndarray]:
    """Band 0 plastic (broad white lobe on a coloured base), 1 metal (sharp tinted lobe), 2 brushed (anisotropic)."""
    b = fidelity._bands

    def rgb(k, ranges):
        return np.stack([b(n, k, c, ranges) for c in range(3)], axis=-1)

    def one(k, ranges):
        return b(n, k, 0, ranges)[..., None]

    ones = np.ones((n, n, 1))
    n1 = one(1, [(10.0, 30.0), (60.0, 150.0), (30.0, 80.0)])
    albedo = one(2, [(0.1, 0.2), (0.3, 0.45), (0.25, 0.4)])
    tint = np.concatenate([one(3, [(0.9, 1.0), (0.8, 1.0), (0.6, 0.8)]), one(4, [(0.9, 1.0), (0.6, 0.8), (0.6, 0.8)]),
                           one(5, [(0.9, 1.0), (0.3, 0.5), (0.5, 0.7)])], axis=-1)
    band = np.arange(n)[None, :, None] * 3 // n
    brushed = band == 2
    # |C| ≥ C_z = 1: the forward lobes rise toward grazing, by |C|^n ≈ 3–5× at the horizon (Fresnel's order)
    c1 = np.choose(band, [-1.04, -1.01, -1.02]) * ones
    return {
        "rho_d": rgb(6, [(0.05, 0.16), (0.01, 0.03), (0.02, 0.06)]),
        "rho_s_1": albedo * (n1 + 2) / (2 * np.pi) * tint,
        "c_x_1": c1, "c_y_1": np.where(brushed, -0.95, c1), "c_z_1": ones.copy(), "exponent_1": n1,
        # lobe 2: a broad forward sheen, rising toward grazing everywhere
        "rho_s_2": rgb(7, [(0.03, 0.08)] * 3), "c_x_2": -1.05 * ones, "c_y_2": -1.05 * ones, "c_z_2": ones.copy(),
        "exponent_2": one(8, [(3.0, 6.0)] * 3),
        # lobe 3: back-scatter
        "rho_s_3": rgb(9, [(0.04, 0.12)] * 3), "c_x_3": 0.9 * ones, "c_y_3": 0.9 * ones, "c_z_3": ones.copy(),
        "exponent_3": one(10, [(2.0, 4.0)] * 3),
        "beta": np.where(brushed, one(11, [(0.3, 0.6)] * 3), 0.0),
    }


def graph_text(folder: Path, texels: int, common: dict | None = None) -> str:
    """The benchmark's graph; ``common``: Fit node parameters of every fit (``--coherence``)."""
    lines = ["name: fit-benchmark", "store: ./store", "nodes:",
             f"  cap: {{kind: Capture, plugin: folder, params: {{path: {json.dumps(str(folder))}}}}}",
             f"  reg: {{kind: Register, plugin: aruco, in: {{capture: cap}}, "
             f"params: {{texels: [{texels}, {texels}], max_rms_mm: 0.5}}}}",
             "  refl: {kind: Reflectance, in: {stack: reg}}"]
    fits = {**FITS, "laf2_alone": FITS["laf2"]}
    for name, (model, mp) in fits.items():
        start = f", start: {STARTS[name]}" if name in STARTS else ""
        lines.append(f"  {name}: {{kind: Fit, plugin: lm, in: {{samples: refl{start}}}, "
                     f"params: {json.dumps({'model': model, 'model_params': mp, **(common or {})})}}}")
    return "\n".join(lines) + "\n"


def run_node(gpath: Path, node: str, workers: int) -> tuple[float, float]:
    """Run ``node`` alone (its inputs cached) on ``workers`` dask threads: (wall s, process CPU s)."""
    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner

    runner = Runner(scheduler="threads", num_workers=workers, progress=False)
    graph = load_graph(gpath, runner.registry)
    shutil.rmtree(Path(graph.url(node)), ignore_errors=True)
    c0 = time.process_time()
    report = runner.run(graph, only=[node])
    cpu = time.process_time() - c0
    (rec,) = [r for r in report.nodes if r.node == node]
    return rec.wall_s, cpu


def write_docs(figures: dict, line: str, size: dict) -> None:
    """The ``fit_engine`` section of docs/accuracy-vs-time.md: a row per model."""
    from report import machine, replace_section

    rows = ["| fit | model | ms CPU / texel | converged | training RMS | held-out RMS | median error, unseen pairs |",
            "|---|---|---:|---:|---:|---:|---:|"]
    for k, (model, mp) in FITS.items():
        rows.append(f"| {k} | {model} {json.dumps(mp) if mp else ''} | {figures[f'{k}_ms']:.3g} | "
                    f"{figures[f'{k}_conv']:.4f} | {figures[f'{k}_train']:.4g} | {figures[f'{k}_held']:.4g} | "
                    f"{figures[f'{k}_err']:.3g} |")
    section = "\n".join([
        "<!-- fit_engine:begin (generated by benchmarks/fit.py --docs; do not edit by hand) -->",
        "### Every model through the fitting engine",
        "",
        f"A virtual capture ({size['texels']}² texels, {size['orbit']} poses, ArUco registration) of a 3-lobe "
        "anisotropic Lafortune material with lobes rising toward grazing, fitted by `lm` with its defaults "
        "(`benchmarks/fit.py`).",
        "",
        *rows,
        "",
        f"Machine: {machine()}.",
        "",
        f"`{line}`",
        "<!-- fit_engine:end -->",
        ""])
    replace_section("fit_engine", section)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="32x32 texels, 150 poses (about a minute)")
    ap.add_argument("--keep", metavar="DIR", default=None, help="work in DIR and keep it")
    ap.add_argument("--docs", action="store_true", help="rewrite the fit_engine section of docs/accuracy-vs-time.md")
    ap.add_argument("--coherence", choices=("neighbours", "pyramid", "none"), default=None,
                    help="the Fit nodes' coherence (default: the node's own default), for a paired comparison")
    args = ap.parse_args(argv)
    size = QUICK if args.quick else FULL
    n = int(size["texels"])  # an int in both sizes; the dicts hold the float focal length too
    workdir = Path(args.keep).resolve() if args.keep else Path(tempfile.mkdtemp(prefix="sbrdf-fit-"))
    workdir.mkdir(parents=True, exist_ok=True)
    try:
        from sbrdf_core.cli import tune_process
        from sbrdf_core.graph import load_graph
        from sbrdf_core.registry import default_registry
        from sbrdf_core.runner import Runner
        from sbrdf_core.store import open_artifact

        tune_process()
        reg = default_registry()
        truth_url = str(workdir / "truth")
        fidelity.write_param_maps(truth_url, reg.create("brdf-model", TRUTH[0], TRUTH[1]), TRUTH[1], truth_maps(n))
        folder = workdir / "capture"
        t0 = time.perf_counter()
        if not (folder / "capture.json").exists():
            fidelity.capture(folder, truth_url, "orbit", size, seed=0)
        log(f"capture: {size['orbit']} poses, {time.perf_counter() - t0:.1f} s")
        gpath = workdir / "graph.yaml"
        gpath.write_text(graph_text(folder, n, {"coherence": args.coherence} if args.coherence else None))
        # warm() reads only each fit's model and model params: no truth material ("") or scans to name here
        fidelity.FITS = {k: ("", (), m, mp) for k, (m, mp) in FITS.items()}
        fidelity.warm(workdir / "warm")  # compile (or load) every model's kernels off the clock
        t0 = time.perf_counter()
        Runner(progress=False).run(load_graph(gpath, reg), only=["refl"])
        log(f"register + reflectance: {time.perf_counter() - t0:.1f} s")
        graph = load_graph(gpath, reg)
        figures: dict[str, float] = {}
        rms_maps = {}
        for name in FITS:
            wall, cpu = run_node(gpath, name, 1)
            art = open_artifact(graph.url(name), kind="ParamMaps")
            summary = art.attrs.get("summary", {})
            samples = np.asarray(art.read("samples")).reshape(-1)
            flags = np.asarray(art.read("flags")).reshape(-1).astype(np.uint8)
            rms_maps[name] = np.asarray(art.read("rms"), np.float64).reshape(-1)
            from sbrdf_core.nodes.fit import NOT_CONVERGED

            has = samples > 0
            s = fidelity.score(graph.url(name), truth_url)
            figures[f"{name}_ms"] = 1e3 * cpu / (n * n)
            figures[f"{name}_conv"] = float(((flags[has] & NOT_CONVERGED) == 0).mean()) if has.any() else float("nan")
            figures[f"{name}_train"] = float(summary.get("rms_mean", float("nan")))
            figures[f"{name}_held"] = float(summary.get("rms_holdout_mean", float("nan")))
            figures[f"{name}_err"] = float(np.median(s["rel"]))
            log(f"{name}: {figures[f'{name}_ms']:.3f} ms CPU/texel ({wall:.1f} s wall), converged "
                f"{figures[f'{name}_conv']:.4f}, train {figures[f'{name}_train']:.5f}, held-out "
                f"{figures[f'{name}_held']:.5f}, median error at unseen pairs {figures[f'{name}_err']:.4f}")
        run_node(gpath, "laf2_alone", 1)
        alone = np.asarray(open_artifact(graph.url("laf2_alone"), kind="ParamMaps").read("rms"), np.float64)

        def worse(l2, l1):
            return int((l2 > l1 * (1 + 1e-6) + 1e-12).sum())

        nested_worse, nested_alone = worse(rms_maps["laf2"], rms_maps["laf1"]), worse(alone.reshape(-1), rms_maps["laf1"])
        ratios = []
        for k in range(int(size["pairs"])):
            order = (1, 2) if k % 2 == 0 else (2, 1)
            walls = {w: run_node(gpath, "laf2", w)[0] for w in order}
            ratios.append(walls[1] / walls[2])
            log(f"laf2 with 1 thread {walls[1]:.2f} s, 2 threads {walls[2]:.2f} s")
        scaling = statistics.median(ratios)
        conv_min = min(figures[f"{k}_conv"] for k in FITS)

        def g(x):
            return f"{x:.4g}"

        head = " ".join(f"{k}_ms={g(figures[f'{k}_ms'])}" for k in ("laf1", "laf2", "ward", "ct", "ggxa"))
        rest = " ".join(f"{k}_{m}={g(figures[f'{k}_{m}'])}" for k in FITS for m in ("ms", "conv", "train", "held", "err"))
        line = (f"fit: {head} converged_min={g(conv_min)} nested_worse={nested_worse} scaling_2={g(scaling)} "
                f"nested_alone={nested_alone} "
                f"texels={n * n} poses={size['orbit']} {rest}")
        if args.docs:
            write_docs(figures, line, size)
        print(line, flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
