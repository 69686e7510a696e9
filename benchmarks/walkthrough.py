"""Walkthrough frame rates: Mühlbacher's Tables 4.1 and 4.2 (seed 004 §8.2–8.3) on this machine, with errors.

What it measures
----------------
Frames per second of the ``gl`` renderer for 3, 5, …, 19 deterministic
samples per lobe, in the thesis's two layouts:

- Table 4.1, curved surfaces lit from a cube map: a glossy Lafortune sphere
  (n = 120) in the procedural HDR sky (``sbrdf_envmap.procedural``, cube
  faces 32²) drawn with the environment's deterministic filtered in-lobe
  sampling (§4.4.3); *full*: the sphere covers the whole screen, *half*:
  about half of it (the rest is a diffuse floor).  The cube map here is
  the environment's; a per-object one (``cube_map:``) runs the same loop.
- Table 4.2, a planar reflector: a glossy floor with ``reflector: true``
  (one mirror pass and its MIP chain per frame, §4.5) reflecting a diffuse
  sphere and cylinder; *full*: the floor covers the screen, *half*: about
  half.

Times are wall clock per frame to ``glFinish`` (every pass; llvmpipe's GL
time queries miss its deferred rasterisation): the fastest of the timed
frames after one warm-up frame, the least disturbed on a shared machine.

Error: relative RMS over the sphere's pixels of the full-screen Table 4.1
frame against the converged reference, the environment's ``progressive``
method (unbiased QMC, MIS of cosine and lobe sampling, unfiltered) run for
8 frames × 128 samples per strategy.

Sizes: full = 1680×1050 (the thesis's), 3 timed frames; ``--quick`` =
336×210, 5 timed frames (about a minute).  ``--docs`` puts the table into
docs/walkthrough.md (the section of the size that ran).

Last line: ``walkthrough: fps_full_7=... fps_half_7=... fps_mirror_full_7=... err_7=... err_19=... device=...``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from report import machine  # noqa: E402

SAMPLES = (3, 5, 7, 9, 11, 13, 15, 17, 19)
GLOSSY = "{model: lafortune, params: {rho_d: 0.02, rho_s_1: 1.0, c_xy_1: -1.0, c_z_1: 1.0, exponent_1: 120}}"
FLOOR = "{model: lafortune, params: {rho_d: 0.05, rho_s_1: 31.8, c_xy_1: -1.0, c_z_1: 1.0, exponent_1: 200}}"

CUBE = """
camera: {{position: {eye}, look_at: [0.0, 0.0, 0.5], fov_deg: 40, resolution: [{W}, {H}]}}
antialias: 1
materials:
  m: {GLOSSY}
  ground: {{model: lambert, params: {{rho_d: 0.1}}}}
objects:
  - {{shape: sphere, radius: 0.5, segments: [128, 64], material: m, transform: {{translate: [0, 0, 0.5]}}}}
  - {{shape: plane, size: [40, 40], material: ground}}
environment: {{file: {env}, options: {{size: 32, diffuse_size: 16, {method}}}}}
"""

MIRROR = """
camera: {{position: {eye}, look_at: {look}, fov_deg: 40, resolution: [{W}, {H}]}}
antialias: 1
materials:
  floor: {FLOOR}
  ball: {{model: lambert, params: {{rho_d: [0.2, 0.1, 0.04]}}}}
  post: {{model: lambert, params: {{rho_d: [0.04, 0.1, 0.2]}}}}
objects:
  - {{shape: plane, size: [6, 6], material: floor, reflector: true}}
  - {{shape: sphere, radius: 0.4, segments: [64, 32], material: ball, transform: {{translate: [0.3, 0.2, 0.4]}}}}
  - {{shape: cylinder, radius: 0.2, height: 1.0, segments: 64, material: post, transform: {{translate: [-0.5, 0.6, 0.5]}}}}
lights:
  - {{type: directional, direction: [0.3, -0.5, 1.0], irradiance: 2.0}}
mirror: {{samples: {K}}}
"""

#: (eye, look_at) per coverage: full screen and about half.
CUBE_EYES = {"full": "[0.0, -0.62, 0.5]", "half": "[0.0, -1.4, 0.65]"}
MIRROR_EYES = {"full": ("[0.5, -1.8, 1.3]", "[0.2, -0.6, 0.0]"), "half": ("[0.0, -2.6, 0.8]", "[0.0, 0.0, 0.3]")}


def frame_times(text: str, timed: int, read: bool = False):
    """(fastest wall ms of ``timed`` frames after a warm-up: the least disturbed on a shared machine, last image)."""
    from sbrdf_core.registry import default_registry
    from sbrdf_lib.scene import load_scene
    from sbrdf_render import materials as mat
    from sbrdf_render.gl import GLScene

    scene = load_scene(text)
    s = GLScene(scene, mat.resolve(scene, None, default_registry()))
    try:
        s.draw(read=False)
        ms = []
        image = None
        for k in range(timed):
            f = s.draw(read=read and k == timed - 1)
            ms.append(f.wall_ms)
            image = f.image if f.image is not None else image
        return float(np.min(ms)), image
    finally:
        s.release()


def specular_fraction(text: str) -> float:
    """Fraction of the screen the specular object (object 0) covers, by ray casting an 84×52 grid."""
    import dataclasses

    from sbrdf_core.registry import default_registry
    from sbrdf_lib.scene import load_scene
    from sbrdf_lib.surface import cast
    from sbrdf_render import materials as mat

    scene = load_scene(text)
    scene = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, resolution=(84, 52)))
    dirs, origin = scene.camera.rays()
    _, which = cast(scene, mat.resolve(scene, None, default_registry()), dirs.reshape(-1, 3), origin)
    return float((which == 0).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="336x210 instead of 1680x1050")
    ap.add_argument("--docs", action="store_true", help="rewrite the table of docs/walkthrough.md")
    args = ap.parse_args()
    W, H = (336, 210) if args.quick else (1680, 1050)
    timed = 5 if args.quick else 3
    import tempfile

    from sbrdf_core.io import write_exr
    from sbrdf_envmap.procedural import sky
    from sbrdf_render.gl import device_name

    tmp = Path(tempfile.mkdtemp(prefix="sbrdf-walkthrough-bench-"))
    env = tmp / "sky.exr"
    write_exr(str(env), sky())
    t_start = time.perf_counter()
    for cov in ("full", "half"):
        eye, look = MIRROR_EYES[cov]
        cube = specular_fraction(CUBE.format(eye=CUBE_EYES[cov], W=W, H=H, GLOSSY=GLOSSY, env=env,
                                             method="method: sampling"))
        mirror = specular_fraction(MIRROR.format(eye=eye, look=look, W=W, H=H, FLOOR=FLOOR, K=7))
        print(f"specular coverage {cov}: cube map {cube:.2f}, mirror {mirror:.2f}", flush=True)
    rows: dict[str, dict[int, float]] = {k: {} for k in ("full", "half", "mirror_full", "mirror_half")}
    errs: dict[int, float] = {}
    ref_text = CUBE.format(eye=CUBE_EYES["full"], W=W, H=H, GLOSSY=GLOSSY, env=env,
                           method="method: progressive, mc_samples: 128")
    _, ref = frame_times(ref_text, 8, read=True)  # 8 progressive frames: the running mean of 8 × 128 per strategy
    ref = ref.astype(np.float64)
    for K in SAMPLES:
        for cov in ("full", "half"):
            text = CUBE.format(eye=CUBE_EYES[cov], W=W, H=H, GLOSSY=GLOSSY, env=env,
                               method=f"method: sampling, samples: {K}")
            ms, image = frame_times(text, timed, read=(cov == "full"))
            rows[cov][K] = 1000.0 / ms
            if cov == "full":
                mask = np.abs(ref).sum(-1) > 0
                errs[K] = float(np.sqrt(((image - ref)[mask] ** 2).mean() / (ref[mask] ** 2).mean()))
            eye, look = MIRROR_EYES[cov]
            ms, _ = frame_times(MIRROR.format(eye=eye, look=look, W=W, H=H, FLOOR=FLOOR, K=K), timed)
            rows["mirror_" + cov][K] = 1000.0 / ms
        print(f"{K:2d} samples: cube map full {rows['full'][K]:6.2f} fps, half {rows['half'][K]:6.2f}; mirror full "
              f"{rows['mirror_full'][K]:6.2f}, half {rows['mirror_half'][K]:6.2f}; err {errs[K]:.4f}", flush=True)
    device = device_name()
    head = f"{W}x{H}, {device}; {machine()}; {time.perf_counter() - t_start:.0f} s"
    table = ["| samples | 4.1 full (fps) | 4.1 half (fps) | 4.2 full (fps) | 4.2 half (fps) | error, 4.1 full |",
             "|---|---|---|---|---|---|"]
    table += [f"| {K} | {rows['full'][K]:.2f} | {rows['half'][K]:.2f} | {rows['mirror_full'][K]:.2f} | "
              f"{rows['mirror_half'][K]:.2f} | {errs[K]:.4f} |" for K in SAMPLES]
    dev = "llvmpipe" if "llvmpipe" in device.lower() else device.split()[0].lower() if device else "unknown"
    line = (f"walkthrough: fps_full_7={rows['full'][7]:.4g} fps_half_7={rows['half'][7]:.4g} "
            f"fps_mirror_full_7={rows['mirror_full'][7]:.4g} fps_mirror_half_7={rows['mirror_half'][7]:.4g} "
            f"err_7={errs[7]:.4g} err_19={errs[19]:.4g} device={dev}")
    if args.docs:
        write_docs("quick" if args.quick else "full", "\n".join([head + ":", ""] + table + ["", f"`{line}`"]))
    print("\n" + head)
    print("\n".join(table))
    print(line)


def write_docs(size: str, block: str) -> None:
    """Replace the ``walkthrough-<size>`` section of docs/walkthrough.md with ``block``."""
    page = ROOT / "docs" / "walkthrough.md"
    text = page.read_text()
    begin, end = f"<!-- walkthrough-{size}:begin -->", f"<!-- walkthrough-{size}:end -->"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + begin + "\n" + block + "\n" + end + rest.split(end, 1)[1]
        page.write_text(text)


if __name__ == "__main__":
    main()
