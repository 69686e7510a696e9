"""Fitting on the GPU: lm-gl (compute shaders) against lm (CPU) on the same SBRDF.

What it measures
----------------
A ``SampleModel`` node draws a 2-lobe Lafortune SBRDF (procedural maps over
the model's typical ranges, 400 direction pairs per texel, noise σ = 0.01
sr⁻¹) into a SampledReflectance on disk.  Then, end to end from that zarr
store, for 1 and 2 lobes: the samples are read tile by tile (``read``), each
tile goes through the Fit node's own tile kernel (:func:`fit_tile`: limits,
held-out split, bounds, flags) with the ``lm-gl`` fitter, and the parameter
maps are written to a zarr store (``write``).  The fitter's time is split
into ``upload`` (packing samples and writing the SSBOs), ``compute``
(dispatches and read-back), and ``cpu`` (starting points, texels refitted on
the CPU because they left their limits or float32 left them unconverged, and
the node's own per-tile work).  The same tiles go through ``lm`` for the
reference RMS and time.

``texels_per_s_lm2`` = texels / (read + fit + write) of lm-gl, 2 lobes;
``rms_ratio_vs_cpu`` = mean training RMS of lm-gl / mean of lm, 2 lobes;
``wall_4096_lm2_s``: the 4096² run, only where the device is a real GPU
(``nan`` on Mesa llvmpipe, which is the CPU).

The big case (lm-gl, 2 lobes, end to end like the rows above) runs at
``--big SIDE`` texels per side (default 4096; ``0`` skips it).  Its
SampleModel store is about SIDE² × 400 pairs × 13 B (f_r float32 RGB and the
validity byte, uncompressed): at 4096² about 90 GB.  The graph's own size
check (``sbrdf_core.estimate``: the nodes' output bytes against the free space
of the store's filesystem) refuses it when it would not fit, and the case is
skipped with that message.  The big case is the Fit node itself, run as
``sbrdf run`` runs it (dask's threaded scheduler, one thread per core: tiles
fitted in parallel, lm-gl's GL calls queued on its one GL thread), lm-gl and
then lm, from the same store to a parameter-map store.  It prints its own line
``big: side=... texels=... wall_lm2_s=... texels_per_s=... lm_wall_lm2_s=...
lm_texels_per_s=... threads=...``; ``wall_4096_lm2_s`` is lm-gl's wall time
only when SIDE is 4096, ``nan`` otherwise (nothing is extrapolated).  The rows
above it fit one tile at a time on one thread, to split the time.

Sizes: full = 256×256 texels (65 536); ``--quick`` = 32×32 — about a minute
on 2 cores with llvmpipe.

Last line: ``fit_gpu: texels=... texels_per_s_lm2=... rms_ratio_vs_cpu=... wall_4096_lm2_s=... device=...``
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

POSES = 400
NOISE = 0.01
TILE = 64  # texels per side of a fit tile: 4096 texels per lm-gl call


def sample_graph(workdir: Path, side: int, seed: int = 0) -> str:
    sample = {"model": "lafortune", "model_params": {"lobes": 2}, "texels": [side, side], "poses": POSES,
              "noise": NOISE, "seed": seed, "directions": "random", "max_theta_deg": 80.0, "tile": min(TILE, side)}
    return f"name: fit-gpu\nstore: {workdir / 'store'}\nnodes:\n  samples: {{kind: SampleModel, params: {json.dumps(sample)}}}\n"


def make_samples(workdir: Path, side: int, seed: int = 0):
    from sbrdf_core.runner import run_graph

    run_graph(sample_graph(workdir, side, seed), progress=False)
    return workdir / "store" / "samples"


def big_graph(workdir: Path, side: int) -> str:
    """:func:`sample_graph` and two Fit nodes on its samples, Lafortune 2 lobes: ``fit_gl`` (lm-gl), ``fit_cpu`` (lm)."""
    fit = json.dumps({"model": "lafortune", "model_params": {"lobes": 2}})
    return sample_graph(workdir, side) + "".join(
        f"  {name}: {{kind: Fit, plugin: {plugin}, in: {{samples: samples}}, params: {fit}}}\n"
        for name, plugin in (("fit_gl", "lm-gl"), ("fit_cpu", "lm")))


def run_big(work: Path, side: int) -> float:
    """The big case at ``side``² texels: lm-gl's Fit node wall time, ``nan`` when skipped.

    The Fit nodes run as ``sbrdf run`` runs them: dask's threaded scheduler, one thread per core, tiles fitted in
    parallel (lm-gl's GL calls queue on its one GL thread; its starting points and the node's own work run in the
    tasks).  A graph whose store would not fit the disk is refused by the graph's own size check
    (:mod:`sbrdf_core.estimate`), and the case is skipped with its message.
    """
    from sbrdf_core.errors import GraphError
    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner

    runner = Runner(progress=False)
    try:
        graph = load_graph(big_graph(work / "big", side), runner.registry)
    except GraphError as e:
        print(f"big: side={side} skipped: " + " ".join(str(e).split()))
        return float("nan")
    t0 = time.perf_counter()
    runner.run(graph, only=["samples"])
    made = time.perf_counter() - t0
    gl, cpu = (runner.run(graph, only=[name])[name].wall_s for name in ("fit_gl", "fit_cpu"))
    print(f"big: side={side} texels={side * side} wall_lm2_s={gl:.1f} texels_per_s={side * side / gl:.0f} "
          f"lm_wall_lm2_s={cpu:.1f} lm_texels_per_s={side * side / cpu:.0f} threads={os.cpu_count()} "
          f"make_samples_s={made:.1f}")
    return gl


def run(samples_path: Path, out_path: Path, plugin: str, lobes: int) -> dict:
    """Read, fit (the Fit node's tile kernel) and write every tile; seconds per stage and the RMS map."""
    import zarr

    from sbrdf_core.nodes.fit import EXTRA, FitOptions, fit_tile
    from sbrdf_core.registry import Registry
    from sbrdf_core.store import open_artifact

    reg = Registry()
    cfg = {"lobes": lobes}
    model = reg.create("brdf-model", "lafortune", cfg)
    params = {"model": "lafortune", "model_params": cfg}
    fitter = reg.create("fitter", plugin, params)
    options = FitOptions()
    art = open_artifact(str(samples_path))
    texels, size_mm = tuple(art.attrs["texels"]), tuple(art.attrs["size_mm"])
    light, camera = art.read("light_pos"), art.read("camera_pos")
    f_store, v_store = art.array("f_r"), art.array("valid")
    V, U = f_store.shape[:2]
    K = model.size + len(EXTRA)
    out = zarr.open_array(str(out_path), mode="w", shape=(V, U, K), chunks=(TILE, TILE, K), dtype="f4")
    t = {"read_s": 0.0, "fit_s": 0.0, "write_s": 0.0}
    rms = np.zeros((V, U))
    for v0 in range(0, V, TILE):
        for u0 in range(0, U, TILE):
            v1, u1 = min(v0 + TILE, V), min(u0 + TILE, U)
            t0 = time.perf_counter()
            f = np.asarray(f_store[v0:v1, u0:u1])
            valid = np.asarray(v_store[v0:v1, u0:u1])
            t1 = time.perf_counter()
            info = [{"array-location": [(v0, v1), (u0, u1)]}]
            res = fit_tile(f, valid[..., None] if valid.ndim == 3 else valid, light, camera, texels, size_mm,
                           fitter, model, options, block_info=info)
            t2 = time.perf_counter()
            out[v0:v1, u0:u1] = res
            t3 = time.perf_counter()
            t["read_s"] += t1 - t0
            t["fit_s"] += t2 - t1
            t["write_s"] += t3 - t2
            rms[v0:v1, u0:u1] = res[..., model.size + EXTRA.index("rms")]
    gpu = getattr(fitter, "timings", {})
    if gpu:
        t["upload_s"], t["compute_s"] = gpu.get("upload_s", 0.0), gpu.get("compute_s", 0.0)
        t["cpu_s"] = t["fit_s"] - t["upload_s"] - t["compute_s"]
        t["cpu_texels"] = gpu.get("cpu_texels", 0.0)
        t["stepwise_texels"] = gpu.get("stepwise_texels", 0.0)
        t["stepwise_s"] = gpu.get("stepwise_s", 0.0)
    t["wall_s"] = t["read_s"] + t["fit_s"] + t["write_s"]
    t["rms"] = float(np.mean(rms))
    return t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="32×32 texels (about a minute on 2 cores)")
    ap.add_argument("--docs", action="store_true", help="accepted for `sbrdf bench`; this benchmark writes no docs")
    ap.add_argument("--big", type=int, default=4096, metavar="SIDE",
                    help="texels per side of the big lm-gl 2-lobe case on a real GPU (default 4096; 0 skips it); "
                         "skipped, saying so, when the graph's size check finds its store would not fit the disk")
    args = ap.parse_args(argv)
    from sbrdf_fitters.lm_gl_device import device_name

    side = 32 if args.quick else 256
    device = device_name()
    software = "llvmpipe" in device.lower() or "softpipe" in device.lower()
    print(f"device: {device}; {side}×{side} texels, {POSES} pairs")
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        samples = make_samples(work, side)
        warm = make_samples(work / "warm", 8, seed=1)
        for lobes in (1, 2):  # compiled kernels and shaders built before anything is timed
            for plugin in ("lm-gl", "lm"):
                run(warm, work / "warm" / f"{plugin}-{lobes}.zarr", plugin, lobes)
        for lobes in (1, 2):
            for plugin in ("lm-gl", "lm"):
                r = run(samples, work / f"{plugin}-{lobes}.zarr", plugin, lobes)
                rows[(plugin, lobes)] = r
                split = " ".join(f"{k}={v:.2f}" for k, v in r.items() if k.endswith("_s"))
                extra = (f" stepwise_texels={int(r['stepwise_texels'])} cpu_texels={int(r['cpu_texels'])}"
                         if "cpu_texels" in r else "")
                print(f"{plugin:6s} lobes={lobes}: {split} texels/s={side * side / r['wall_s']:.0f} "
                      f"rms={r['rms']:.5f}{extra}")
        wall_4096 = float("nan")
        if not software and args.big > 0:
            wall = run_big(work, args.big)
            if args.big == 4096:
                wall_4096 = wall
    gl2, cpu2 = rows[("lm-gl", 2)], rows[("lm", 2)]
    name = "llvmpipe" if "llvmpipe" in device.lower() else device.split("(")[0].strip().replace(" ", "_")
    print(f"fit_gpu: texels={side * side} texels_per_s_lm2={side * side / gl2['wall_s']:.1f} "
          f"rms_ratio_vs_cpu={gl2['rms'] / cpu2['rms']:.4f} wall_4096_lm2_s={wall_4096:.1f} device={name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
