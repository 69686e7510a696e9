"""Register (aruco) + Reflectance on a virtual capture of about N GB, local threads and a LocalCluster.

What it measures
----------------
The ``virtual-camera`` photographs a Lambertian sample of constant albedo
``a = 0.5`` (100 mm, on the ArUco carrier; 640x480 pixels, focal 900 px, lens
distortion; effects falloff, blur, motor_error) from ``P`` poses
(``orbit_poses``), written by ``capture_to_folder`` as float32 EXR.  ``P`` is
chosen so the CaptureSet holds ``--gb`` GB of float32 RGB (P·H·W·3·4 bytes).
The graph capture (``folder``) -> register (``aruco``, 256x256 texels) ->
reflectance runs once to build the CaptureSet (not timed), then Register +
Reflectance are timed (the runner's node wall times) on

``threads``  dask's threaded scheduler in this process, and
``cluster``  a ``distributed.LocalCluster`` (2 worker processes, 1 thread each),
             started under ``sbrdf_core.runner.CLUSTER_CONFIG`` (docs/cluster.md).

``mb_per_s`` = CaptureSet MB / (Register + Reflectance seconds), threads run.
``peak_rss_mb`` = peak resident set of the process running Register +
Reflectance plus its children (cluster workers), sampled every 50 ms; the
larger of the two runs.  Each run is a fresh process, as ``sbrdf run`` is, so
the memory this script used to make the capture does not count.  With
``--quick`` the threaded run is also done at half the size, so the two
peaks show whether memory grows with the scan (it must not: the stack is
stored in texel tiles and the transpose streams one tile of all poses at a time).
``read_s`` = a plain read of the same CaptureSet (every pose's ``images`` and
``valid`` chunk, read with zarr one after the other in a fresh process, no dask,
right after the timed run, so the page cache is as warm for it as for the
run; the median of three such processes): the bytes Register must read.
``read_ratio`` = (Register + Reflectance seconds) / ``read_s`` (target ≤ 2).
``stack_read_s`` is the same plain read of the registered stack (Reflectance's
input) and ``reflectance_read_ratio`` = Reflectance seconds / ``stack_read_s``.
The project's own reads of aligned chunks skip zarr's per-chunk overhead
(``sbrdf_core.store._shards``), so Reflectance can take less time than this
plain zarr read of its input.
``register_floor_s`` = what Register cannot go below with its resampling filter
on this machine: every accepted pose's photograph read through the node's own
reads, reduced to its pyramid level and remapped bicubically at each of its
sub-samples (``cv2.remap``), on one thread per core, and nothing else (no pose
measurement, masks, edge handling or writes; the maps are made off the clock),
in a fresh process right after the run; ``read_ratio_floor`` = (``register_floor_s``
+ Reflectance seconds) / ``read_s``: the ``read_ratio`` a Register doing only
that would give.
``peak_rss_mb_<size>gb`` = the threaded run's peak RSS at two sizes, each in a
fresh process: 0.5 and 2 GB at full size, ``--gb``/2 and ``--gb`` with
``--quick`` (the two must agree within 10 %: memory flat in the scan).  A single
run's peak varies about ±15 % from run to run at the same size, so at full size
each size's threaded run is repeated (``--repeats``, 3) and the medians are
reported (times too); ``peak_ratio`` = the larger size's median / the smaller's.
``registration_rms_texel`` = mean homography RMS (mm) / texel size (mm).
``lambert_err`` = max over every valid texel and pose of |f_r·π/a − 1|.

A known spatially varying SBRDF (not scaled with ``--gb``): the same camera
photographs a 1-lobe Lafortune material with the ``synthetic`` procedural
maps on a 256x256 texel grid from ``LAF_POSES`` poses (effects falloff, blur,
motor_error), through the same graph on threads.  Every valid f_r sample is
compared with the model at that texel's true parameters and its own ω_i, ω_r
(registered light and camera positions,
``VirtualCamera.reference_f_r``); the relative errors |f_r/f_true − 1| of
every channel give ``median_rel_err`` and ``p95_rel_err``.  ``per_pose_*``
are the same figures for the per-pose shortcut the text warns against (the
sample centre's r, cos θ_i, ω_i and ω_r for every texel).  They are printed
on the line before the last::

    lafortune: poses=<int> texels=<int> median_rel_err=<float> p95_rel_err=<float> per_pose_median=<float> per_pose_p95=<float>

How to run
----------
::

    python benchmarks/reflectance.py [--gb 2] [--quick] [--tmpdir DIR] [--no-cluster] [--scan DIR] [--repeats N]

Full size is 2 GB (``--gb 8`` also works: disk ≈ 2x the GB for the folder plus
the stores); ``--quick`` is 0.1 GB (about a minute on 2 cores).  Progress to
stderr; the last line of stdout is::

    reflectance: gb=<float> mb_per_s=<float> peak_rss_mb=<float> registration_rms_texel=<float> lambert_err=<float>
        register_s=<float> reflectance_s=<float> read_s=<float> read_ratio=<float> stack_read_s=<float>
        reflectance_read_ratio=<float> peak_rss_mb_<a>gb=<float> peak_rss_mb_<b>gb=<float> peak_ratio=<float>
        repeats=<int> register_floor_s=<float> read_ratio_floor=<float>

(one line).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

W, H, FOCAL, TEXELS, ALBEDO = 640, 480, 900.0, 256, 0.5
LAF_POSES = 24


class PeakRSS:
    """Samples this process's RSS plus its children's every 50 ms (psutil).

    ``peak`` is the peak of the sum; ``peak_main`` and ``peak_children`` the peaks of
    this process (client, and a LocalCluster's scheduler) and of the children (workers)
    alone, printed to stderr to show which side grows.
    """

    def __init__(self):
        import psutil

        self.proc = psutil.Process()
        self.peak = self.peak_main = self.peak_children = 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _sample(self) -> int:
        main, children = self.proc.memory_info().rss, 0
        for c in self.proc.children(recursive=True):
            try:
                children += c.memory_info().rss
            except Exception:
                pass
        self.peak_main, self.peak_children = max(self.peak_main, main), max(self.peak_children, children)
        return main + children

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self._sample())
            time.sleep(0.05)

    def __enter__(self):
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, self._sample())


def poses_for(gb: float) -> int:
    """Poses whose float32 RGB photographs make ``gb`` GB."""
    return max(4, int(round(gb * 1e9 / (W * H * 3 * 4))))


def make_capture(folder: Path, gb: float) -> int:
    from sbrdf_capture.photograph import capture_to_folder, orbit_poses
    from sbrdf_core.registry import default_registry

    P = poses_for(gb)
    reg = default_registry()
    cam = reg.create("device", "virtual-camera", {"width": W, "height": H, "focal_px": FOCAL, "texels": [64, 64],
                                                  "model": "lambert", "intensity": 1.5e5, "motor_light_mm": 0.0,
                                                  "effects": ["falloff", "blur", "motor_error"]})
    cam.bind(reg)
    cam._maps = {"rho_d": np.full((64, 64, 3), ALBEDO / np.pi)}  # constant albedo (lambert's rho_d is in sr^-1)
    light, R, t = orbit_poses(P, max_camera_theta_deg=45.0)
    t0 = time.perf_counter()
    capture_to_folder(cam, folder, light, R, t, [[1.0]] * P, durable=False, image_format="png",
                      progress=lambda d, n: print(f"\rcapture {d}/{n}", end="", file=sys.stderr) if d % 20 == 0 else None)
    print(f"\rvirtual capture: {P} poses in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return P


def graph(path: Path, folder: Path, store: Path) -> Path:
    path.write_text(f"""name: reflectance-bench
store: {store}
nodes:
  capture: {{kind: Capture, plugin: folder, params: {{path: '{folder}'}}}}
  register: {{kind: Register, plugin: aruco, in: {{capture: capture}}, params: {{texels: [{TEXELS}, {TEXELS}], edge_margin_px: 2.0}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}}}
""")
    return path


def timed_run(g: Path, scheduler: str) -> tuple[float, float, dict]:
    """Run the graph in fresh processes, as ``sbrdf run`` would: first the capture
    node alone (untimed), then Register + Reflectance, timed and with their peak
    RSS sampled.  A fresh process keeps this script's own leftovers (the virtual
    capture it just made) out of the figure."""
    import json
    import subprocess

    def child(*nodes: str) -> dict:
        cmd = [sys.executable, __file__, "--child", str(g), "--scheduler", scheduler, *[f"--node={n}" for n in nodes]]
        out = subprocess.run(cmd, stdout=subprocess.PIPE, check=True, text=True).stdout
        return json.loads(out.strip().splitlines()[-1])

    t0 = time.perf_counter()
    child("capture")
    print(f"  {scheduler}: capture node (folder -> CaptureSet, untimed) {time.perf_counter() - t0:.1f} s",
          file=sys.stderr, flush=True)
    r = child("reflectance")
    print(f"  register {r['register_s']:.1f} s, reflectance {r['reflectance_s']:.1f} s, peak RSS {r['peak']:.0f} MB "
          f"(runner process {r['peak_main']:.0f} MB, workers {r['peak_children']:.0f} MB)", file=sys.stderr, flush=True)
    return r["register_s"] + r["reflectance_s"], r["peak"], r


def plain_read(artifact: Path, names: tuple[str, ...]) -> float:
    """Seconds to read every chunk (shard) of ``names`` of a stored artifact with plain zarr, in a fresh process."""
    import json
    import subprocess

    cmd = [sys.executable, __file__, "--read", str(artifact), *[f"--node={n}" for n in names]]
    out = subprocess.run(cmd, stdout=subprocess.PIPE, check=True, text=True).stdout
    return float(json.loads(out.strip().splitlines()[-1])["read_s"])


def read_child(artifact: str, names: list[str]) -> None:
    """``--read``: what a user's loop over the stored arrays costs: one zarr read per stored chunk (shard), in order."""
    import json

    import zarr

    g = zarr.open_group(artifact, mode="r")
    t0 = time.perf_counter()
    total = 0.0
    for name in names:
        z = g[name]
        assert isinstance(z, zarr.Array), name  # the names are the artifact's arrays (the caller lists them)
        step = (z.shards or z.chunks)[0]
        for p0 in range(0, z.shape[0], step):
            total += float(np.asarray(z[p0:p0 + step]).ravel()[:1].sum())  # touch: the bytes are decoded
    print(json.dumps({"read_s": time.perf_counter() - t0, "touch": total}))


def register_floor(store: Path) -> float:
    """Seconds of :func:`floor_child` on ``store``'s capture and registration, in a fresh process."""
    import json
    import subprocess

    cmd = [sys.executable, __file__, "--floor", str(store)]
    out = subprocess.run(cmd, stdout=subprocess.PIPE, check=True, text=True).stdout
    return float(json.loads(out.strip().splitlines()[-1])["floor_s"])


def floor_child(store: str, block: int = 32) -> None:
    """``--floor``: wall seconds for every accepted pose's read and bicubic remaps alone (``register_floor_s``).

    Poses go in blocks: a block's maps are made first, off the clock (all of them would not fit in memory at
    8 GB), then its poses are read and remapped on one thread per core, on the clock.
    """
    import json
    from concurrent.futures import ThreadPoolExecutor

    import cv2

    from sbrdf_core.store import open_artifact
    from sbrdf_register.aruco import subsample_offsets, texel_maps

    cv2.setNumThreads(1)  # as under the runner: the pool's threads are the parallelism (sbrdf_core._runtime)
    capture, reg = open_artifact(f"{store}/capture"), open_artifact(f"{store}/register")
    images, valid = capture.zarr_array("images"), capture.zarr_array("valid")
    U, V = reg.attrs["texels"]
    size = tuple(reg.attrs["size_mm"])
    K, dist = np.asarray(reg.attrs["registration"]["K"], float), np.asarray(reg.attrs["registration"]["dist"], float)
    ids, H = reg.read("pose_ids"), reg.read("homography")
    levels, subsamples = reg.read("registration/pyramid_level"), reg.read("registration/subsamples")

    def maps_of(k: int) -> list:
        n_u, n_v = (int(n) for n in subsamples[k])
        return [texel_maps((U, V), size, offset, H[k], K, dist, 2.0 ** -int(levels[k]))
                for offset in subsample_offsets(n_u, n_v)]

    def resample(job) -> None:
        k, maps = job
        image: np.ndarray = np.asarray(images[int(ids[k])], np.float32)  # pyrDown below: any dtype, per cv2's stub
        np.asarray(valid[int(ids[k])])  # read, as Register reads it, though only the remaps' time is wanted of it
        for _ in range(int(levels[k])):
            image = cv2.pyrDown(image)
        for mx, my in maps:
            cv2.remap(image, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    seconds = 0.0
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        for k0 in range(0, len(ids), block):
            jobs = [(k, maps_of(k)) for k in range(k0, min(k0 + block, len(ids)))]
            t0 = time.perf_counter()
            list(pool.map(resample, jobs))
            seconds += time.perf_counter() - t0
    print(json.dumps({"floor_s": seconds, "poses": len(ids)}))


def child_run(g: str, scheduler: str, nodes: list[str]) -> None:
    """``--child``: run ``nodes`` of graph ``g`` on ``threads`` or a 2-worker LocalCluster; print JSON figures."""
    import contextlib
    import json

    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner

    with contextlib.ExitStack() as stack:
        target = scheduler
        if scheduler == "cluster":
            import dask
            from distributed import Client, LocalCluster

            from sbrdf_core.runner import CLUSTER_CONFIG

            stack.enter_context(dask.config.set(CLUSTER_CONFIG))
            lc = stack.enter_context(LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                  dashboard_address=None))
            target = stack.enter_context(Client(lc))
        runner = Runner(scheduler=target)
        gr = load_graph(g, runner.registry)
        with PeakRSS() as mem:
            rep = runner.run(gr, only=nodes)
    walls = {f"{n.node}_s": n.wall_s for n in rep.nodes}
    print(json.dumps({**walls, "peak": mem.peak / 2**20, "peak_main": mem.peak_main / 2**20,
                      "peak_children": mem.peak_children / 2**20}))


def summarise(store: Path) -> tuple[float, float, float]:
    from sbrdf_core.store import open_artifact

    st = open_artifact(str(store / "register"))
    rms_texel = float(st.attrs["registration"]["rms_texel_mean"])
    fr = open_artifact(str(store / "reflectance"))
    f, valid = fr.zarr_array("f_r"), fr.zarr_array("valid")
    worst, n_valid, n = 0.0, 0, 0
    tv = f.chunks[0]
    for v0 in range(0, f.shape[0], tv):  # tile rows at a time: never the whole array
        fv, vv = f[v0:v0 + tv], valid[v0:v0 + tv]
        if vv.any():
            worst = max(worst, float(np.abs(fv[vv] * np.pi / ALBEDO - 1).max()))
        n_valid += int(vv.sum())
        n += vv.size
    return rms_texel, worst, n_valid / max(n, 1)


def one(tmp: Path, gb: float, cluster: bool, scan: Path | None = None, keep: bool = False, repeats: int = 1) -> dict:
    folder = scan or tmp / f"scan-{gb:g}"
    P = poses_for(gb)
    if scan is not None and (scan / "capture.json").exists() and len(os.listdir(scan / "images")) == P:
        print(f"virtual capture: {P} poses kept in {scan}", file=sys.stderr)
    else:
        shutil.rmtree(folder, ignore_errors=True)
        make_capture(folder, gb)
    mb = P * W * H * 3 * 4 / 1e6
    out = {"P": P, "mb": mb}
    store = tmp / f"store-{gb:g}-threads"
    runs = []
    for k in range(repeats):  # each a fresh process; the medians are reported (peak RSS varies ±15 % run to run)
        for node in ("register", "reflectance") if k else ():  # the CaptureSet stays: only the timed nodes again
            shutil.rmtree(store / node, ignore_errors=True)
        runs.append(timed_run(graph(tmp / "g.yaml", folder, store), "threads"))
    med = lambda xs: float(np.median(xs))  # noqa: E731
    secs, peak = med([r[0] for r in runs]), med([r[1] for r in runs])
    if repeats > 1:
        print(f"  {gb:g} GB threads, {repeats} runs: peak RSS {' '.join(f'{r[1]:.0f}' for r in runs)} MB "
              f"(median {peak:.0f}), seconds {' '.join(f'{r[0]:.1f}' for r in runs)}", file=sys.stderr, flush=True)
    out.update(threads_s=secs, threads_peak=peak,
               register_s=med([r[2]["register_s"] for r in runs]), reflectance_s=med([r[2]["reflectance_s"] for r in runs]))
    # The plain reads, right after the run (the same page cache): the capture Register reads, the stack Reflectance
    # reads.  Medians of three fresh processes each: one read of the same files varied 2.0-3.5 s here.
    out["read_s"] = med([plain_read(store / "capture", ("images", "valid")) for _ in range(3)])
    out["stack_read_s"] = med([plain_read(store / "register", ("radiance", "valid")) for _ in range(3)])
    out["floor_s"] = med([register_floor(store) for _ in range(3)])
    print(f"plain read: capture {out['read_s']:.2f} s (ratio {secs / out['read_s']:.2f}), registered stack "
          f"{out['stack_read_s']:.2f} s (Reflectance ratio {out['reflectance_s'] / out['stack_read_s']:.2f})",
          file=sys.stderr, flush=True)
    print(f"Register's floor (reads and bicubic remaps alone): {out['floor_s']:.2f} s against {out['register_s']:.2f} s",
          file=sys.stderr, flush=True)
    out["rms_texel"], out["lambert_err"], out["valid"] = summarise(store)
    print(f"threads: {P} poses, {mb:.0f} MB in {secs:.1f} s = {mb / secs:.1f} MB/s, peak RSS {peak:.0f} MB; "
          f"registration RMS {out['rms_texel']:.3f} texel; lambert max err {out['lambert_err']:.4f}; "
          f"valid {out['valid']:.2f}", flush=True)
    shutil.rmtree(store, ignore_errors=True)
    if cluster:
        store = tmp / f"store-{gb:g}-cluster"
        secs, peak, _ = timed_run(graph(tmp / "gc.yaml", folder, store), "cluster")
        rms, err, _ = summarise(store)
        out.update(cluster_s=secs, cluster_peak=peak, cluster_err=err)
        print(f"cluster (2 workers): {mb:.0f} MB in {secs:.1f} s = {mb / secs:.1f} MB/s, peak RSS (all processes) "
              f"{peak:.0f} MB; lambert max err {err:.4f}", flush=True)
        shutil.rmtree(store, ignore_errors=True)
    if scan is None and not keep:
        shutil.rmtree(folder, ignore_errors=True)
    return out


def lafortune(tmp: Path) -> dict:
    """A 1-lobe Lafortune SBRDF (procedural maps) on the texel grid: per-sample relative errors, per texel and per pose."""
    from sbrdf_capture.photograph import capture_to_folder, orbit_poses
    from sbrdf_core.registry import default_registry
    from sbrdf_core.store import open_artifact

    reg = default_registry()
    cam = reg.create("device", "virtual-camera", {"width": W, "height": H, "focal_px": FOCAL, "texels": [TEXELS, TEXELS],
                                                  "model": "lafortune", "model_params": {"lobes": 1}, "intensity": 1.5e5,
                                                  "motor_light_mm": 0.0, "effects": ["falloff", "blur", "motor_error"]})
    cam.bind(reg)
    folder, store = tmp / "scan-lafortune", tmp / "store-lafortune"
    light, R, t = orbit_poses(LAF_POSES, max_camera_theta_deg=45.0)
    capture_to_folder(cam, folder, light, R, t, [[1.0]] * LAF_POSES, durable=False)
    timed_run(graph(tmp / "gl.yaml", folder, store), "threads")
    fr = open_artifact(str(store / "reflectance"))
    st = open_artifact(str(store / "register"))
    lp, cp = fr.read("light_pos"), fr.read("camera_pos")
    f, valid, rad = fr.zarr_array("f_r"), fr.zarr_array("valid"), st.zarr_array("radiance")
    P = lp.shape[0]
    r_c = np.linalg.norm(lp, axis=-1)
    pp_scale = r_c**2 / (cam.intensity * lp[:, 2] / r_c)  # the sample centre's r² / (I cos θ_i), per pose
    wi_c, wo_c = lp / r_c[:, None], cp / np.linalg.norm(cp, axis=-1, keepdims=True)
    maps = cam.ground_truth()
    rel_parts: list[np.ndarray] = []
    rel_pp_parts: list[np.ndarray] = []
    tv = f.chunks[0]
    for v0 in range(0, f.shape[0], tv):  # tile rows at a time
        v1 = min(v0 + tv, f.shape[0])
        vv = valid[v0:v1]
        truth = cam.reference_f_r((TEXELS, TEXELS), lp, cp, rows=(v0, v1))
        rel_parts.append(np.abs(f[v0:v1][vv] / truth[vv] - 1).ravel())
        T = (v1 - v0) * TEXELS
        params = {k: m[v0:v1].reshape(T, -1) for k, m in maps.items()}
        truth_pp = cam.model.eval(params, np.broadcast_to(wi_c, (T, P, 3)), np.broadcast_to(wo_c, (T, P, 3)))
        f_pp = np.moveaxis(rad[:, v0:v1] * pp_scale[:, None, None, None], 0, 2)
        rel_pp_parts.append(np.abs(f_pp[vv] / truth_pp.reshape(f_pp.shape)[vv] - 1).ravel())
    rel, rel_pp = np.concatenate(rel_parts), np.concatenate(rel_pp_parts)
    shutil.rmtree(store, ignore_errors=True)
    shutil.rmtree(folder, ignore_errors=True)
    return {"median": float(np.median(rel)), "p95": float(np.percentile(rel, 95)),
            "pp_median": float(np.median(rel_pp)), "pp_p95": float(np.percentile(rel_pp, 95))}


def main() -> None:
    from sbrdf_core._runtime import limit_arenas, single_level

    limit_arenas()  # as the sbrdf CLI does for its runs: the memory figures assume capped malloc arenas
    single_level()  # and, for a parallel run, OpenCV's pool off (children inherit it; the cluster's workers get it)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--gb", type=float, default=None, help="CaptureSet size in GB (default 2; --quick 0.1)")
    ap.add_argument("--quick", action="store_true", help="0.1 GB, plus a half-size threads run for the memory check")
    ap.add_argument("--tmpdir", default=None)
    ap.add_argument("--no-cluster", action="store_true", help="skip the LocalCluster run")
    ap.add_argument("--scan", type=Path, default=None,
                    help="keep the virtual capture in this folder and reuse it on the next run of the same size")
    ap.add_argument("--repeats", type=int, default=None,
                    help="threaded runs per size, each in a fresh process; medians reported (default 3; --quick 1)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--scheduler", help=argparse.SUPPRESS)
    ap.add_argument("--node", action="append", help=argparse.SUPPRESS)
    ap.add_argument("--read", help=argparse.SUPPRESS)
    ap.add_argument("--floor", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child_run(args.child, args.scheduler, args.node)
    if args.read:
        return read_child(args.read, args.node)
    if args.floor:
        return floor_child(args.floor)
    gb = args.gb if args.gb is not None else (0.1 if args.quick else 2.0)
    tmp = Path(tempfile.mkdtemp(prefix="sbrdf-reflectance-", dir=args.tmpdir))
    try:
        small = gb / 2 if args.quick or args.gb is not None else 0.5
        repeats = args.repeats if args.repeats is not None else (1 if args.quick else 3)
        half = one(tmp, small, cluster=False, repeats=repeats)
        print(f"memory check: peak RSS {half['threads_peak']:.0f} MB at {small:g} GB", flush=True)
        r = one(tmp, gb, cluster=not args.no_cluster, scan=args.scan, repeats=repeats)
        peak = max(r["threads_peak"], r.get("cluster_peak", 0.0))
        err = max(r["lambert_err"], r.get("cluster_err", 0.0))
        lf = lafortune(tmp)
        print(f"lafortune: poses={LAF_POSES} texels={TEXELS} median_rel_err={lf['median']:.4f} p95_rel_err={lf['p95']:.4f} "
              f"per_pose_median={lf['pp_median']:.4f} per_pose_p95={lf['pp_p95']:.4f}", flush=True)
        key = lambda g: f"peak_rss_mb_{g:g}gb".replace(".", "_")  # noqa: E731
        print(f"reflectance: gb={r['mb'] / 1e3:.3f} mb_per_s={r['mb'] / r['threads_s']:.1f} peak_rss_mb={peak:.0f} "
              f"registration_rms_texel={r['rms_texel']:.3f} lambert_err={err:.4f} register_s={r['register_s']:.2f} "
              f"reflectance_s={r['reflectance_s']:.2f} read_s={r['read_s']:.2f} "
              f"read_ratio={r['threads_s'] / r['read_s']:.2f} stack_read_s={r['stack_read_s']:.2f} "
              f"reflectance_read_ratio={r['reflectance_s'] / r['stack_read_s']:.2f} "
              f"{key(small)}={half['threads_peak']:.0f} {key(gb)}={r['threads_peak']:.0f} "
              f"peak_ratio={r['threads_peak'] / half['threads_peak']:.3f} repeats={repeats} "
              f"register_floor_s={r['floor_s']:.2f} "
              f"read_ratio_floor={(r['floor_s'] + r['reflectance_s']) / r['read_s']:.2f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    main()
