"""The Fit node's speed-up with dask threads, measured from the graph runner.

What it measures
----------------
One graph, as a user runs it::

    samples (SampleModel, lafortune 1 lobe, procedural maps, 150 poses, noise 0.005, 32² tiles)
      -> fit (Fit, lm, lafortune 1 lobe, every other option the default)

The samples are written once; then the ``fit`` node alone is run again and
again on the same samples (its artifact deleted before each run), with
``Runner(scheduler="threads", num_workers=W)`` for W = 1 and W = 2, in turns
(1, 2, 2, 1, 1, 2, ...: each pair in the other order, so the machine's changes
of speed reach both alike).  Per run: the Fit node's ``wall_s`` from the run
report and the process's CPU time over the run (``time.process_time``: all
threads, numba's included).  The process is set up as ``sbrdf run`` sets up
its own (``sbrdf_core.cli.tune_process``: malloc arenas, OpenCV's pool).
Kernels are compiled or loaded off the clock first (one untimed run of each
worker count on a small graph).

``threadsW_s``: the median Fit wall time with W threads; ``scaling_2``: the
median over pairs of (1-thread wall / 2-thread wall of the same pair);
``cores_W``: median CPU time / wall time with W threads (how many cores the
node kept busy).  numba's own threads (``NUMBA_NUM_THREADS``, the machine's
cores by default) run inside each task either way.

Sizes: full (no arguments) = 256×256 texels, 3 pairs; ``--quick`` = 128×128
texels, 3 pairs (about a minute on 2 cores once the kernels are cached; the
first run on a machine compiles them first, minutes).

Last line: ``fit_scaling: texels=... threads1_s=... threads2_s=... scaling_2=...
cores_1=... cores_2=...`` (plain numbers).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

GRAPH = textwrap.dedent("""\
    name: fit-scaling
    store: {store}
    nodes:
      samples: {{kind: SampleModel, params: {{model: lafortune, model_params: {{lobes: 1}}, texels: [{n}, {n}],
                poses: 150, noise: 0.005, tile: 32}}}}
      fit: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lafortune}}}}
    """)


def run_fit(graph_path: Path, store: Path, workers: int) -> tuple[float, float]:
    """Run the ``fit`` node alone (the samples are cached) with ``workers`` dask threads: (wall s, CPU s)."""
    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner

    shutil.rmtree(store / "fit", ignore_errors=True)
    runner = Runner(scheduler="threads", num_workers=workers)
    graph = load_graph(graph_path, runner.registry)
    c0 = time.process_time()
    report = runner.run(graph, only=["fit"])
    cpu = time.process_time() - c0
    (fit,) = [r for r in report.nodes if r.node == "fit"]
    assert fit.status == "computed", fit.status
    return fit.wall_s, cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="128×128 texels (about a minute)")
    args = ap.parse_args()
    n, pairs = (128, 3) if args.quick else (256, 3)

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from report import machine

    from sbrdf_core.cli import tune_process

    tune_process(argparse.Namespace(scheduler="threads", workers=2))
    print(machine())
    tmp = Path(tempfile.mkdtemp(prefix="sbrdf-fit-scaling-"))
    try:
        graphs = {}
        for name, size in (("warm", 32), ("timed", n)):
            store = tmp / name
            path = tmp / f"{name}.yaml"
            path.write_text(GRAPH.format(store=store, n=size))
            graphs[name] = (path, store)
        t0 = time.perf_counter()
        from sbrdf_core.graph import load_graph
        from sbrdf_core.runner import Runner

        for name in ("warm", "timed"):
            runner = Runner(scheduler="threads")
            runner.run(load_graph(graphs[name][0], runner.registry), only=["samples"])
        for workers in (1, 2):
            run_fit(*graphs["warm"], workers)
        print(f"warm-up (samples written, kernels compiled or loaded): {time.perf_counter() - t0:.1f} s wall")

        walls: dict[int, list[float]] = {1: [], 2: []}
        cores: dict[int, list[float]] = {1: [], 2: []}
        for pair in range(pairs):
            for workers in ((1, 2) if pair % 2 == 0 else (2, 1)):
                wall, cpu = run_fit(*graphs["timed"], workers)
                walls[workers].append(wall)
                cores[workers].append(cpu / wall)
                print(f"pair {pair + 1}, {workers} thread(s): Fit {wall:.2f} s wall, {cpu:.2f} s CPU "
                      f"({cpu / wall:.2f} cores)", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    scaling = statistics.median(a / b for a, b in zip(walls[1], walls[2]))
    print(f"fit_scaling: texels={n * n} threads1_s={statistics.median(walls[1]):.3f} "
          f"threads2_s={statistics.median(walls[2]):.3f} scaling_2={scaling:.3f} "
          f"cores_1={statistics.median(cores[1]):.2f} cores_2={statistics.median(cores[2]):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
