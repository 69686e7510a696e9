"""A batch of N small scans on a LocalCluster against the same scans run one after the other.

One graph with a ``${seed}`` variable (synthetic capture -> texel-aligned
registration -> reflectance -> Lambert fit) is run for N seeds:

``sequential``  in this process, one scan after the other, each on dask's
                threaded scheduler (what a loop of ``sbrdf run --var seed=...``
                does, without the interpreter start-up);
``batch``       :func:`sbrdf_core.batch.run_batch` on a ``distributed.LocalCluster``
                (2 worker processes, 1 thread each, under
                ``sbrdf_core.runner.CLUSTER_CONFIG``), ``--concurrent`` scans in
                flight at once (default 4; every node's dask keys name its
                artifact, so scans on one scheduler never share a task).

The batch's fitted maps are checked against the sequential ones, scan by scan.

Both get one untimed warm-up scan first (imports, the fitter's compiled
kernels, the workers' imports), into stores of their own.  Both write fresh
stores, so neither reuses the other's artifacts.  Wall time; the same cores
(all of this machine's).  ``ratio`` = batch_s / sequential_s (below 1: the
batch is faster).

    .venv/bin/python benchmarks/batch.py --quick     # under a minute on 2 cores
    .venv/bin/python benchmarks/batch.py             # a few minutes on 2 cores

Last line: ``batch: scans=... batch_s=... sequential_s=... ratio=...``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

GRAPH = """\
name: batch-bench
store: {store}
variables:
  seed: 0
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [{n}, {n}], poses: {poses}, noise: 0.01, seed: "${{seed}}"}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}, params: {{tile: {tile}}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lambert}}}}
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="4 scans of 32x32 texels x 24 poses (about a minute)")
    ap.add_argument("--scans", type=int, default=None, help="number of scans (default 4 quick, 10 full)")
    ap.add_argument("--texels", type=int, default=None, help="texels per side (default 32 quick, 64 full)")
    ap.add_argument("--poses", type=int, default=None, help="poses per scan (default 24 quick, 48 full)")
    ap.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes (default 2)")
    ap.add_argument("--concurrent", type=int, default=4, help="scans in flight at once in the batch (default 4)")
    ap.add_argument("--docs", action="store_true", help="accepted for `sbrdf bench`; this stage has no docs section")
    args = ap.parse_args()
    scans = args.scans or (4 if args.quick else 10)
    n = args.texels or (32 if args.quick else 64)
    poses = args.poses or (24 if args.quick else 48)

    import dask
    from distributed import Client, LocalCluster

    from sbrdf_core.batch import Scan, run_batch
    from sbrdf_core.graph import load_graph
    from sbrdf_core.registry import Registry
    from sbrdf_core.runner import CLUSTER_CONFIG, Runner

    reg = Registry()
    with tempfile.TemporaryDirectory(prefix="sbrdf-batch-bench-") as tmp:
        root = Path(tmp)
        graph = root / "graph.yaml"
        graph.write_text(GRAPH.format(store=root / "unused", n=n, poses=poses, tile=min(32, n)))
        seeds = list(range(1, scans + 1))

        # sequential: one after the other in this process, threaded scheduler
        Runner(reg).run(load_graph(graph, reg, store=str(root / "warm-seq"), variables={"seed": "999"}))
        t0 = time.perf_counter()
        for seed in seeds:
            Runner(reg).run(load_graph(graph, reg, store=str(root / "seq" / f"s{seed}"), variables={"seed": str(seed)}))
        sequential_s = time.perf_counter() - t0
        print(f"sequential: {scans} scans of {n}x{n} texels x {poses} poses in {sequential_s:.2f} s "
              f"(threads, {os.cpu_count()} cores)", flush=True)

        # batch: a LocalCluster, scans submitted by run_batch
        with dask.config.set(CLUSTER_CONFIG), \
                LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                             dashboard_address=":0") as cluster, Client(cluster) as client:
            run_batch(graph, [Scan("warm", {"seed": "998"})], reg, scheduler=client, store=str(root / "warm-batch"),
                      echo=None)
            t0 = time.perf_counter()
            report = run_batch(graph, [Scan(f"s{seed}", {"seed": str(seed)}) for seed in seeds], reg,
                               scheduler=client, store=str(root / "batch"), echo=None, concurrent=args.concurrent)
            batch_s = time.perf_counter() - t0
        print(report.table(), flush=True)
        assert not report.failed, [s.error for s in report.failed]
        import numpy as np

        from sbrdf_core.store import open_artifact

        for seed in seeds:  # the same maps as the sequential run, scan by scan
            a = open_artifact(str(root / "batch" / f"s{seed}" / "fit")).read("params/rho_d")
            b = open_artifact(str(root / "seq" / f"s{seed}" / "fit")).read("params/rho_d")
            assert np.allclose(a, b, rtol=1e-5, atol=1e-6), f"scan s{seed}: batch and sequential fits differ"
        print(f"batch: {scans} scans on a LocalCluster ({args.workers} workers x 1 thread, {args.concurrent} "
              f"scans at a time) in {batch_s:.2f} s", flush=True)
    print(f"batch: scans={scans} texels={n}x{n} poses={poses} workers={args.workers} "
          f"concurrent={args.concurrent} batch_s={batch_s:.2f} sequential_s={sequential_s:.2f} "
          f"ratio={batch_s / sequential_s:.2f}")


if __name__ == "__main__":
    main()
