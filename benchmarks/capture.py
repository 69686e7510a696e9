"""Throughput of a virtual gonioreflectometer capture into an sbrdf-capture/1 folder.

What it measures
----------------
The ``virtual-camera`` device (built through ``default_registry().create("device",
"virtual-camera", ...)``, Lambertian procedural material, 256x256 texels, 1024x768
pixels, lens distortion) photographs ``poses`` poses (camera and light on two
Fibonacci spirals, ``sbrdf_cameras.virtual.orbit_poses``) and
``sbrdf_cameras.virtual.capture_to_folder`` writes them, one exposure per pose,
into a fresh capture folder (``durable=True``: every image and journal line is
fsynced, as a real capture would), then finishes the manifest.  Two runs:

``all effects``
    every effect: falloff, vignetting, blur, motor_error, dark_current, noise,
    saturation, response (8-bit sRGB) -> uint8 PNG images.
``no effects``
    none: linear float32 radiance with uniform irradiance -> OpenEXR (ZIP) images.

The timing (``time.perf_counter``) covers rendering, the sensor model, image
encoding and writing; the one-time ray precomputation and model binding are
done before the clock starts (a warm-up photograph).  Peak memory is the
process's peak resident set size (``resource.getrusage``) at the end.

How to run
----------
::

    python benchmarks/capture.py [--quick] [--poses N] [--tmpdir DIR]

Full size is 500 poses each way; ``--quick`` is 60 poses each way (about a minute
on 2 cores).  Progress goes to stderr; the last line of stdout is::

    capture: poses=<int> all_effects_poses_per_s=<float> no_effects_poses_per_s=<float> peak_rss_mb=<float>
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

FULL, QUICK = 500, 60
ALL_EFFECTS = ["falloff", "vignetting", "blur", "motor_error", "dark_current", "noise", "saturation", "response"]


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run(folder: Path, poses: int, effects: list[str]) -> float:
    from sbrdf_cameras.virtual import capture_to_folder, orbit_poses
    from sbrdf_core.registry import default_registry

    registry = default_registry()
    cam = registry.create("device", "virtual-camera", {"width": 1024, "height": 768, "effects": effects})
    cam.bind(registry)
    light, R, t = orbit_poses(poses)
    cam.photograph(light[0], R[0], t[0], 1.0, pose_id=10**9)  # warm-up: rays, carrier, model
    t0 = time.perf_counter()
    m = capture_to_folder(cam, folder, light, R, t, 1.0, durable=True)
    dt = time.perf_counter() - t0
    if len(m.poses) != poses or set(effects) != cam.effects_ran:
        raise RuntimeError(f"capture wrote {len(m.poses)} poses, ran effects {sorted(cam.effects_ran)}")
    size = sum(p.stat().st_size for p in (folder / "images").iterdir())
    log(f"  {len(effects)} effects: {poses} poses in {dt:.1f} s ({poses / dt:.2f} poses/s), images {size / 2**20:.0f} MiB")
    return poses / dt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help=f"{QUICK} poses each way instead of {FULL}")
    ap.add_argument("--poses", type=int, default=None, help="override the pose count")
    ap.add_argument("--tmpdir", default=None, help="where the temporary capture folders go")
    args = ap.parse_args(argv)
    poses = args.poses or (QUICK if args.quick else FULL)
    log(f"capture: {poses} poses at 1024x768, {os.cpu_count()} CPUs")
    with tempfile.TemporaryDirectory(prefix="sbrdf-capture-", dir=args.tmpdir) as tmp:
        all_rate = run(Path(tmp) / "all", poses, ALL_EFFECTS)
        none_rate = run(Path(tmp) / "none", poses, [])
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"capture: poses={poses} all_effects_poses_per_s={all_rate:.2f} no_effects_poses_per_s={none_rate:.2f} "
          f"peak_rss_mb={peak_mb:.0f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
