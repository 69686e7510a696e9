"""Throughput of a virtual gonioreflectometer capture into an sbrdf-capture/1 folder.

What it measures
----------------
The ``virtual-camera`` device (built through ``default_registry().create("device",
"virtual-camera", ...)``, Lambertian procedural material, 256x256 texels, 1024x768
pixels, lens distortion) photographs ``poses`` poses (camera and light on two
Fibonacci spirals, ``sbrdf_capture.photograph.orbit_poses``) and
``sbrdf_capture.photograph.capture_to_folder`` writes them, one exposure per pose,
into a fresh capture folder (``durable=True``: every image and journal line is
fsynced, as a real capture would), then finishes the manifest.  Two runs:

``all effects``
    every effect: falloff, vignetting, blur, motor_error, dark_current, noise,
    saturation, response (8-bit sRGB) -> uint8 PNG images.
``no effects``
    none: linear float32 radiance with uniform irradiance -> OpenEXR (ZIP) images.

Then the whole rig: the ``gonio`` capture source drives the three pty motor
simulators (``port: sim``) through a plan of ``rig_poses`` explicit poses with
a two-exposure bracket, into a capture folder: with the virtual camera; with
the ``pylon`` driver on Basler's emulator (``PYLON_CAMEMU``) serving the
virtual run's photographs as 16-bit RGB frames (skipped when ``pypylon`` is
not installed); with the ``aravis`` driver on Aravis's fake GigE Vision
camera over the loopback interface (skipped when it is not installed); and with
the ``genicam`` driver (harvesters) on the ``genicam`` wheel's virtual producer
``viky.cti``, one fixed exposure since its cameras have no exposure control.  The gonio source's own clock splits each
run into motion (move commands until every motor reports its position),
settle (``settle_s``, 0 here), exposure (the frame camera's integration
time), transfer (trigger to frame in memory, less the exposure; for the
virtual camera: rendering) and write (encoding, fsync, journal).

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

    capture: poses=<int> all_effects_poses_per_s=<float> no_effects_poses_per_s=<float> rig_poses=<int>
    rig_virtual_poses_per_s=<float> rig_pylon_poses_per_s=<float> pylon_motion_s=<float> pylon_settle_s=<float>
    pylon_exposure_s=<float> pylon_transfer_s=<float> pylon_write_s=<float> [rig_aravis_poses_per_s=<float>
    aravis_motion_s=<float> ... aravis_write_s=<float>] [rig_genicam_poses_per_s=<float> genicam_motion_s=<float>
    ... genicam_write_s=<float>] peak_rss_mb=<float>

(one line; the ``pylon_*_s`` and ``aravis_*_s`` figures are seconds per pose; the ``aravis`` figures
appear where ``arv-fake-gv-camera-0.8`` and the Aravis bindings are installed: its frames are the
simulator's test pattern, not the virtual rig's photographs).
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
RIG_FULL, RIG_QUICK = 48, 12
#: Explicit [pan, tilt, roll, light] poses inside the simulated PTU-46 and indexer ranges, light above the sample.
RIG_ANGLES = [[p, t, r, lt] for p in (-20.0, 0.0, 20.0) for t in (-20.0, 10.0) for r in (0.0, 60.0, -60.0, 120.0)
              for lt in (30.0, 60.0)]
RIG_TIMES = [0.0025, 0.01]
ALL_EFFECTS = ["falloff", "vignetting", "blur", "motor_error", "dark_current", "noise", "saturation", "response"]


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run(folder: Path, poses: int, effects: list[str]) -> float:
    from sbrdf_capture.photograph import capture_to_folder, orbit_poses
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


def rig(folder: Path, poses: int, camera: dict, times: list | None = None, **params) -> tuple[float, dict]:
    """One gonio capture of ``poses`` poses (exposure ``times``, default :data:`RIG_TIMES`); ``(poses/s, seconds
    per pose by phase)``."""
    from sbrdf_core.registry import default_registry

    registry = default_registry()
    motors = {"pan": {"device": "ptu", "params": {"port": "sim"}, "axes": {"pan": "pan_deg"}},
              "tilt_roll": {"device": "ptu", "params": {"port": "sim"}, "axes": {"tilt": "tilt_deg", "roll": "pan_deg"}},
              "arm": {"device": "indexer", "params": {"port": "sim"}, "axes": {"light": "angle_deg"}}}
    src = registry.create("capture", "gonio", {"path": str(folder), "motors": motors, "camera": camera,
                                               "plan": {"angles_deg": RIG_ANGLES[:poses]},
                                               "exposures": {"times_s": times or RIG_TIMES}, "durable": True,
                                               **params})
    src.bind(registry)
    src.describe()
    t0 = time.perf_counter()
    src.read_pose(poses - 1)
    dt = time.perf_counter() - t0
    src.close()
    split = {k: v / poses for k, v in src.timings.items()}
    log(f"  rig, {camera['device']}: {poses} poses in {dt:.1f} s ({poses / dt:.2f} poses/s); per pose "
        + ", ".join(f"{k} {v * 1000:.1f} ms" for k, v in split.items()))
    return poses / dt, split


def rigs(tmp: Path, poses: int) -> dict:
    import json

    virtual = {"device": "virtual-camera",
               "params": {"width": 320, "height": 240, "focal_px": 1200.0, "texels": [64, 64], "intensity": 4e6,
                          "sensitivity": 100.0, "effects": ["falloff", "saturation", "response", "noise"],
                          "response_curve": "gamma", "response_gamma": 1.0, "bit_depth": 16}}
    out = {"rig_virtual_poses_per_s": rig(tmp / "rig-virtual", poses, virtual)[0]}
    m = json.loads((tmp / "rig-virtual" / "capture.json").read_text())
    frame_params = {"sample": m["sample"], "light": m["light"],
                    "intrinsics": {"K": m["camera"]["K"], "dist": m["camera"]["dist"]}}
    try:
        import pypylon.pylon  # noqa: F401
    except ImportError:
        log("  rig, pylon: skipped (pip install 'sbrdf[pylon]')")
    else:
        frames = str(tmp / "rig-virtual" / "images" / "p{pose:05d}_e{exposure}.png")
        camera = {"device": "pylon", "params": {"pixel_format": "RGB16Packed", "width": 320, "height": 240,
                                                "emulation_frames": frames}}
        rate, split = rig(tmp / "rig-pylon", poses, camera, **frame_params)
        out["rig_pylon_poses_per_s"] = rate
        out.update({f"pylon_{k}_s": v for k, v in split.items()})
    out.update(aravis_rig(tmp, poses, frame_params))
    out.update(genicam_rig(tmp, poses, frame_params))
    return out


def genicam_rig(tmp: Path, poses: int, frame_params: dict) -> dict:
    """The rig with the ``genicam`` driver (harvesters) on the ``genicam`` wheel's virtual producer ``viky.cti``,
    when both are installed.  Its cameras have no exposure control: one fixed exposure
    (``nominal_exposure_s``), so the capture's own bracket is that one time."""
    try:
        from sbrdf_devices.cameras.genicam import virtual_producer

        viky = virtual_producer()
    except ImportError:
        viky = None
    if viky is None:
        log("  rig, genicam: skipped (pip install 'sbrdf[genicam]')")
        return {}
    camera = {"device": "genicam", "params": {"producer": viky, "serial": "1", "pixel_format": "Mono8", "width": 320,
                                              "height": 240, "nominal_exposure_s": RIG_TIMES[0]}}
    rate, split = rig(tmp / "rig-genicam", poses, camera, read={"response": "linear"}, times=[RIG_TIMES[0]],
                      **frame_params)
    return {"rig_genicam_poses_per_s": rate, **{f"genicam_{k}_s": v for k, v in split.items()}}


def aravis_rig(tmp: Path, poses: int, frame_params: dict) -> dict:
    """The rig with the ``aravis`` driver on Aravis's fake GigE Vision camera (loopback), when both are installed."""
    import shutil
    import subprocess

    fake = shutil.which("arv-fake-gv-camera-0.8")
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError):
        Aravis = None
    if fake is None or Aravis is None:
        log("  rig, aravis: skipped (apt install aravis-tools gir1.2-aravis-0.8; pip install 'sbrdf[aravis]')")
        return {}
    serial = "SBRDF-BENCH"
    proc = subprocess.Popen([fake, "-i", "127.0.0.1", "-s", serial], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            Aravis.update_device_list()
            if any(Aravis.get_device_serial_nbr(i) == serial for i in range(Aravis.get_n_devices())):
                break
            time.sleep(0.1)
        camera = {"device": "aravis", "params": {"serial": serial, "pixel_format": "Mono8", "width": 320,
                                                 "height": 240}}
        rate, split = rig(tmp / "rig-aravis", poses, camera, read={"response": "linear"}, **frame_params)
    finally:
        proc.terminate()
        proc.wait(5)
    return {"rig_aravis_poses_per_s": rate, **{f"aravis_{k}_s": v for k, v in split.items()}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help=f"{QUICK} poses each way instead of {FULL}")
    ap.add_argument("--poses", type=int, default=None, help="override the pose count")
    ap.add_argument("--tmpdir", default=None, help="where the temporary capture folders go")
    args = ap.parse_args(argv)
    poses = args.poses or (QUICK if args.quick else FULL)
    rig_poses = RIG_QUICK if args.quick else RIG_FULL
    os.environ.setdefault("PYLON_CAMEMU", "1")  # one emulated Basler camera, before pypylon first looks
    log(f"capture: {poses} poses at 1024x768, {os.cpu_count()} CPUs")
    with tempfile.TemporaryDirectory(prefix="sbrdf-capture-", dir=args.tmpdir) as tmp:
        all_rate = run(Path(tmp) / "all", poses, ALL_EFFECTS)
        none_rate = run(Path(tmp) / "none", poses, [])
        rig_figures = rigs(Path(tmp), rig_poses)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rig_text = " ".join(f"{k}={v:.4f}" if k.endswith("_s") and not k.endswith("per_s") else f"{k}={v:.2f}"
                        for k, v in rig_figures.items())
    print(f"capture: poses={poses} all_effects_poses_per_s={all_rate:.2f} no_effects_poses_per_s={none_rate:.2f} "
          f"rig_poses={rig_poses} {rig_text} peak_rss_mb={peak_mb:.0f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
