"""Overhead of the sbrdf graph runner against the project's kernels called directly, doing the same work.

What it measures
----------------
The same three-stage pipeline is run two ways, each on a fresh temporary zarr
store, and timed with ``time.perf_counter`` (wall clock):

``graph``
    A three-node YAML graph, written to a temporary directory and run with
    ``Runner(progress=False, scheduler="threads")``::

        capture (Capture, synthetic, model lambert, noise 0)
          -> register (Register, texel-aligned)
          -> reflectance (Reflectance)

    The timing covers loading/validating the graph and the whole run: plugin
    construction, cache tokens, provenance, one write task per chunk
    (``write_chunk``) with its done marker, finalisation and completion checks.

``kernels`` (printed as ``plain_dask_s`` for continuity: there is no dask in it)
    The same computation as a user would write it without the runner: the
    project's kernels called directly from a thread pool with one thread per
    CPU (as many as the graph's threaded scheduler), no dask graph, no
    artifacts, provenance or done markers, each stage written with plain zarr
    into arrays of the graph's layout (shapes, chunks, shards, codecs) and the
    next stage reading them back:

    1. capture: ``sbrdf_core.nodes.capture._read_block`` (the synthetic
       source's ``read_pose``) per pose, one pose per chunk;
    2. register: texel-aligned registration is the identity, so ``images`` and
       ``valid`` are copied into the stack's pose-block shards
       (``sbrdf_core.nodes.register.pose_block``; the graph additionally runs
       its resample kernel, a copy);
    3. reflectance: ``sbrdf_core.nodes.reflectance.reflectance_tile`` per
       texel tile (``sbrdf_core.store.texel_tile``), the tile's poses read from
       the stack, stored as ``f_r`` and ``valid``.

    The small per-pose metadata arrays (light and camera positions, ...) are
    computed in memory instead of being stored.

    The graph reads and writes whole chunks straight from and to their files
    (``sbrdf_core.store._shards``) where plain zarr, as here, goes through its
    per-chunk machinery, so a ratio below 1 is the project's I/O being faster
    than a user's zarr calls, not a runner costing nothing.

Both variants must produce bit-identical ``f_r`` and ``valid`` (all tiles with
``--quick``, a sample of tiles at full size, all with ``--check-all``); the
script exits with status 1 if they do not.

Method: both variants are first run once, untimed, at a tiny size (texels
[32, 32], 4 poses) to import and initialise everything.  Then each variant is
run ``--repeat`` times (default 3 with ``--quick``, 1 at full size), alternating graph / plain, each on a fresh
store, with ``os.sync()`` before every timed run so dirty pages of the previous
run are not flushed on the next one's clock; the best (minimum) time of each
is reported per stage; ``graph_s`` and ``plain_dask_s`` are the medians and ``ratio`` the median of
the paired ratios (each graph run over the kernels run right after it).  All temporary stores are deleted at the end, also on error.

Sizes: full size (no arguments) is texels [512, 512] x 341 poses, so the
capture ``images`` array is 341*512*512*3*4 B = 1.07e9 B (~1 GiB float32);
``--quick`` is texels [256, 256] x 64 poses (about a minute on 2 cores).

How to run
----------
::

    python benchmarks/overhead.py [--quick] [--repeat N] [--check-all] [--tmpdir DIR]

Progress goes to stderr; the last line of stdout is::

    overhead: graph_s=<float> plain_dask_s=<float> ratio=<float> bytes=<int> poses=.. texels=UxV tile=..

What the numbers mean
---------------------
``graph_s`` and ``plain_dask_s`` are the wall-clock seconds of each variant,
``ratio = graph_s / plain_dask_s`` (1.0 = no overhead; 1.10 = the runner costs
10 % on top of the kernels and the I/O; target ≤ 1.2 at full size), ``bytes`` the size of the
capture ``images`` array.  Per-stage seconds of both variants are printed to
stderr.
"""

from __future__ import annotations

import argparse
import gc
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FULL = ((512, 512), 341)
QUICK = ((256, 256), 64)
WARMUP = ((32, 32), 4)
MIN_COS = 0.02  # the Reflectance node's default


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def capture_params(texels: tuple[int, int], poses: int) -> dict:
    return {"texels": [int(texels[0]), int(texels[1])], "poses": int(poses), "model": "lambert", "noise": 0.0}


# ---------------------------------------------------------------------------
# graph variant
# ---------------------------------------------------------------------------

GRAPH_YAML = """\
name: overhead
description: benchmarks/overhead.py - capture -> register -> reflectance
store: ./store
nodes:
  capture:
    kind: Capture
    plugin: synthetic
    params: {{texels: [{u}, {v}], poses: {p}, model: lambert, noise: 0}}
  register:
    kind: Register
    plugin: texel-aligned
    in: {{capture: capture}}
  reflectance:
    kind: Reflectance
    in: {{stack: register}}
"""


def run_graph_variant(workdir: Path, texels: tuple[int, int], poses: int) -> tuple[float, dict[str, float], Path]:
    """Run the YAML graph on a fresh store under ``workdir``; return (seconds, per-node seconds, store)."""
    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner

    workdir.mkdir(parents=True)
    yaml_path = workdir / "overhead.yaml"
    yaml_path.write_text(GRAPH_YAML.format(u=texels[0], v=texels[1], p=poses))
    store = workdir / "store"
    t0 = time.perf_counter()
    runner = Runner(progress=False, scheduler="threads")
    report = runner.run(load_graph(yaml_path, runner.registry, store=str(store)))
    dt = time.perf_counter() - t0
    for r in report.nodes:
        if r.status != "computed":
            raise RuntimeError(f"graph node {r.node} was {r.status}, expected computed (store not fresh?)")
    return dt, {r.node: r.wall_s for r in report.nodes}, store


# ---------------------------------------------------------------------------
# plain dask variant
# ---------------------------------------------------------------------------


def _pool_map(fn, items) -> None:
    """``fn`` over ``items`` on one thread per CPU (the graph's threaded scheduler has as many)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        for _ in pool.map(fn, items):
            pass


def run_plain_variant(workdir: Path, texels: tuple[int, int], poses: int) -> tuple[float, dict[str, float], Path]:
    """The project's kernels called directly, no dask: a thread pool over poses and tiles writing zarr arrays
    of the graph's layout (chunks, shards, codecs); return (seconds, per-stage seconds, store)."""
    import zarr

    from sbrdf_core.geometry import camera_centre
    from sbrdf_core.nodes.capture import _read_block
    from sbrdf_core.nodes.reflectance import reflectance_tile
    from sbrdf_core.nodes.register import pose_block
    from sbrdf_core.registry import default_registry
    from sbrdf_core.store import texel_tile
    from sbrdf_core.store._artifact import _codecs

    workdir.mkdir(parents=True)
    store = workdir / "store"
    stages: dict[str, float] = {}
    t0 = time.perf_counter()

    def create(group, name, shape, chunks, dtype, shards=None):
        fill = float("nan") if np.dtype(dtype).kind == "f" else 0
        return group.create_array(name, shape=shape, chunks=chunks, shards=shards, dtype=dtype, fill_value=fill,
                                  compressors=_codecs())

    # 1. capture: the node's kernel per pose ----------------------------------------
    registry = default_registry()
    source = registry.create("capture", "synthetic", capture_params(texels, poses))
    source.bind(registry)
    desc = source.describe()
    P, H, W = desc.n_poses, desc.height, desc.width
    g = zarr.open_group(store=str(store / "capture"), mode="w")
    images = create(g, "images", (P, H, W, 3), (1, H, W, 3), "float32")
    valid = create(g, "valid", (P, H, W), (1, H, W), "bool")

    def capture(i: int) -> None:
        out = _read_block(np.array([i]), source)
        images[i:i + 1] = out[..., :3]
        valid[i:i + 1] = out[..., 3] > 0.5

    _pool_map(capture, range(P))
    t1 = time.perf_counter()
    stages["capture"] = t1 - t0

    # 2. register (texel-aligned: identity): pose blocks copied into the stack's shards ---------
    U, V = texels
    k, t = pose_block((V, U), P), texel_tile((V, U), P, channels=4)
    g = zarr.open_group(store=str(store / "register"), mode="w")
    radiance = create(g, "radiance", (P, V, U, 3), (k, t, t, 3), "float32", shards=(k, V, U, 3))
    rvalid = create(g, "valid", (P, V, U), (k, t, t), "bool", shards=(k, V, U))

    def register(p0: int) -> None:
        radiance[p0:p0 + k] = images[p0:p0 + k]
        rvalid[p0:p0 + k] = valid[p0:p0 + k]

    _pool_map(register, range(0, P, k))
    t2 = time.perf_counter()
    stages["register"] = t2 - t1

    # 3. reflectance: the node's kernel per texel tile -----------------------------------------
    width_mm, height_mm = (float(s) for s in desc.sample["size_mm"])
    size_mm = (width_mm, height_mm)
    intensity = float(desc.light["intensity"])
    light_pos = np.asarray(desc.light_pos, float)
    camera_pos = camera_centre(desc.camera_R, desc.camera_t)
    g = zarr.open_group(store=str(store / "reflectance"), mode="w")
    f_r = create(g, "f_r", (V, U, P, 3), (t, t, P, 3), "float32")
    fvalid = create(g, "valid", (V, U, P), (t, t, P), "bool")

    def reflectance(tile: tuple[int, int]) -> None:
        (v0, u0) = tile
        v1, u1 = min(v0 + t, V), min(u0 + t, U)
        out = reflectance_tile(radiance[:, v0:v1, u0:u1], rvalid[:, v0:v1, u0:u1], light_pos, camera_pos, (U, V),
                               size_mm, intensity, MIN_COS, (v0, v1), (u0, u1))
        f_r[v0:v1, u0:u1] = out[..., :3]
        fvalid[v0:v1, u0:u1] = out[..., 3] > 0.5

    _pool_map(reflectance, [(v0, u0) for v0 in range(0, V, t) for u0 in range(0, U, t)])
    t3 = time.perf_counter()
    stages["reflectance"] = t3 - t2
    return t3 - t0, stages, store


# ---------------------------------------------------------------------------
# comparison
# ---------------------------------------------------------------------------


def compare(graph_store: Path, plain_store: Path, check_all: bool) -> tuple[bool, int]:
    """Compare reflectance f_r and valid tile by tile; return (equal, tiles compared)."""
    import zarr

    def array(group: zarr.Group, name: str) -> zarr.Array:
        z = group[name]
        assert isinstance(z, zarr.Array), name  # Reflectance stores f_r and valid as arrays
        return z

    a = zarr.open_group(store=str(graph_store / "reflectance"), mode="r")
    b = zarr.open_group(store=str(plain_store / "reflectance"), mode="r")
    fa, fb = array(a, "f_r"), array(b, "f_r")
    if fa.shape != fb.shape or fa.chunks != fb.chunks or fa.dtype != fb.dtype:
        log(f"f_r differs in layout: graph {fa.shape} {fa.chunks} {fa.dtype}, plain {fb.shape} {fb.chunks} {fb.dtype}")
        return False, 0
    tv, tu = fa.chunks[0], fa.chunks[1]
    nv, nu = -(-fa.shape[0] // tv), -(-fa.shape[1] // tu)
    tiles = [(i, j) for i in range(nv) for j in range(nu)]
    if not check_all:  # corners, centre and a diagonal
        pick = {(0, 0), (0, nu - 1), (nv - 1, 0), (nv - 1, nu - 1), (nv // 2, nu // 2)}
        pick |= {(k * (nv - 1) // 4, k * (nu - 1) // 4) for k in range(5)}
        tiles = sorted(pick)
    for i, j in tiles:
        sl = (slice(i * tv, (i + 1) * tv), slice(j * tu, (j + 1) * tu))
        for name in ("f_r", "valid"):
            x, y = np.asarray(array(a, name)[sl]), np.asarray(array(b, name)[sl])
            if not np.array_equal(x, y, equal_nan=(name == "f_r")):
                log(f"MISMATCH in reflectance/{name} tile ({i}, {j}): max |diff| = "
                    f"{np.nanmax(np.abs(x.astype(float) - y.astype(float)))}")
                return False, len(tiles)
    return True, len(tiles)


# ---------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=f"small size: texels {list(QUICK[0])}, {QUICK[1]} poses")
    ap.add_argument("--repeat", type=int, default=None,
                    help="timed runs per variant; the best is reported (default 3 with --quick, 1 at full size)")
    ap.add_argument("--check-all", action="store_true", help="compare every tile (always on with --quick)")
    ap.add_argument("--tmpdir", default=None, help="where temporary stores go (default: the system temp dir)")
    args = ap.parse_args(argv)
    if args.repeat is None:
        args.repeat = 3 if args.quick else 1
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")

    texels, poses = QUICK if args.quick else FULL
    nbytes = poses * texels[0] * texels[1] * 3 * 4
    check_all = args.check_all or args.quick
    log(f"overhead: texels {texels[0]}x{texels[1]}, {poses} poses, images {nbytes / 2**30:.3f} GiB float32, "
        f"{os.cpu_count()} CPUs, repeat {args.repeat}")

    with tempfile.TemporaryDirectory(prefix="sbrdf-overhead-", dir=args.tmpdir) as tmp:
        root = Path(tmp)
        log("warm-up (untimed) at texels 32x32, 4 poses ...")
        _, _, gs = run_graph_variant(root / "warm-graph", *WARMUP)
        _, _, ps = run_plain_variant(root / "warm-plain", *WARMUP)
        ok, _ = compare(gs, ps, True)
        shutil.rmtree(root / "warm-graph")
        shutil.rmtree(root / "warm-plain")
        if not ok:
            log("FAIL: warm-up results differ")
            return 1

        # per variant the fastest run: (seconds, seconds per stage)
        best: dict[str, tuple[float, dict[str, float]]] = {"graph": (float("inf"), {}), "plain": (float("inf"), {})}
        runs: dict[str, list[float]] = {"graph": [], "plain": []}
        last: dict[str, Path] = {}
        for rep in range(args.repeat):
            for variant, fn in (("graph", run_graph_variant), ("plain", run_plain_variant)):  # paired, alternating
                if variant in last:  # only the latest store of each variant is kept, for the comparison
                    shutil.rmtree(last[variant].parent)
                gc.collect()
                os.sync()
                dt, stages, store = fn(root / f"{variant}-{rep}", texels, poses)
                last[variant] = store
                runs[variant].append(dt)
                log(f"  run {rep + 1}/{args.repeat} {variant:<5}: {dt:8.2f} s  "
                    + "  ".join(f"{k} {v:.2f}" for k, v in stages.items()))
                if dt < best[variant][0]:
                    best[variant] = (dt, stages)

        log("comparing reflectance f_r/valid ...")
        ok, n = compare(last["graph"], last["plain"], check_all)
        if not ok:
            log("FAIL: graph and plain dask results differ")
            return 1
        log(f"  identical ({n} tiles compared)")
        import zarr

        tile = zarr.open_group(store=str(last["graph"] / "reflectance"), mode="r").attrs["tile"]

    # Paired: each repeat's graph run against the kernels run right after it, the median ratio of the pairs.
    ratio = float(np.median([g / p for g, p in zip(runs["graph"], runs["plain"])]))
    graph_s, plain_s = float(np.median(runs["graph"])), float(np.median(runs["plain"]))
    log("per stage (best run), s:  " + "  ".join(
        f"{k} graph {best['graph'][1].get(k, float('nan')):.2f} / plain {best['plain'][1][k]:.2f}" for k in best["plain"][1]))
    print(f"overhead: graph_s={graph_s:.2f} plain_dask_s={plain_s:.2f} ratio={ratio:.3f} bytes={nbytes} "
          f"poses={poses} texels={texels[0]}x{texels[1]} tile={tile} repeat={args.repeat}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
