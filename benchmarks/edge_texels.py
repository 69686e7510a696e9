"""Edge texels: how many texels of the sample grid get no valid sample, ring by ring, and how right the edge ones are.

What it measures
----------------
The capture ``graphs/virtual-scan.yaml``'s header describes (``virtual-camera``,
640x480 pixels, focal 900 px, a ``ward`` material on 64x64 texels, effects
falloff, blur, motor_error, noise, ``orbit_poses(P)``, exposures 0.25 and 1.0)
is written to ``<work>/folder-<P>`` (made once, reused), then run through
``folder`` -> ``aruco`` (64x64 texels, max_rms_mm 0.5; ``--edge``,
``--margin``, ``--min-weight`` set its ``edge``, ``edge_margin_px``,
``edge_min_weight``, default the plugin's) -> ``Reflectance``.  ``--effects``
changes the camera's effects (a separate folder).  Not one of ``sbrdf bench``'s
stages: run it by hand (docs/registration.md, "At the sample edge").
Ring ``k`` is the set of texels ``k`` texels in from the sample edge (ring 0:
the outer ring, 252 texels of 64x64; ``interior``: ring 3 and in).

``unsampled`` = texels with no valid sample over all poses / all texels; per
ring ``ringK=<texels with none>/<texels>``.  ``err_<ring>`` / ``err_p90_<ring>``
= median / 90th percentile over the ring's valid samples of |f_r / truth − 1|
(green channel), ``bias_<ring>`` the median signed error, truth being the
virtual camera's own model at the texel centre and the registered ω_i, ω_r
(``VirtualCamera.reference_f_r``); ``valid_per_texel_<ring>`` = mean number of
valid samples per texel of the ring.

Run from the repository root::

    .venv/bin/python benchmarks/edge_texels.py --work runs/edge-texels --poses 60  # now
    .venv/bin/python benchmarks/edge_texels.py --work runs/edge-texels --poses 60 --edge strict --margin 1  # before

Last line: ``edge_texels: unsampled=... ring0=... ring1=... ring2=... interior=... err_ring0=...
err_ring1=... err_interior=... err_p90_ring0=... err_p90_interior=...`` (``ringK``: texels of the ring with no
valid sample; the ring sizes are in the JSON printed before it).  ``--quick``: 24 poses, about a minute.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

EFFECTS = ["falloff", "blur", "motor_error", "noise"]


def make_camera(effects=EFFECTS):
    from sbrdf_core.registry import default_registry

    reg = default_registry()
    cam = reg.create("device", "virtual-camera", {
        "width": 640, "height": 480, "focal_px": 900.0, "model": "ward", "texels": [64, 64],
        "effects": list(effects), "intensity": 1.5e5})
    cam.bind(reg)
    return cam


def rings(V: int, U: int) -> np.ndarray:
    vv, uu = np.mgrid[0:V, 0:U]
    return np.minimum(np.minimum(vv, V - 1 - vv), np.minimum(uu, U - 1 - uu))


def main(argv=None) -> dict:
    from sbrdf_capture.photograph import capture_to_folder, orbit_poses
    from sbrdf_core.runner import run_graph
    from sbrdf_core.store import open_artifact

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="runs/edge-texels")
    ap.add_argument("--poses", type=int, default=None, help="poses of the orbit (default 60; --quick 24)")
    ap.add_argument("--quick", action="store_true", help="24 poses: about a minute")
    ap.add_argument("--edge", default=None, help="aruco's edge parameter (default: the plugin's default)")
    ap.add_argument("--margin", type=float, default=None, help="aruco's edge_margin_px (default: the plugin's)")
    ap.add_argument("--min-weight", type=float, default=None, help="aruco's edge_min_weight (default: the plugin's)")
    ap.add_argument("--effects", default=",".join(EFFECTS), help="virtual-camera effects, comma-separated")
    a = ap.parse_args(argv)
    a.poses = a.poses or (24 if a.quick else 60)
    work = Path(a.work).resolve()
    effects = [e for e in a.effects.split(",") if e]
    tag = "" if effects == EFFECTS else "-" + "-".join(effects)
    folder = work / f"folder-{a.poses}{tag}"
    cam = make_camera(effects)
    if not (folder / "capture.json").exists():
        t0 = time.perf_counter()
        light, R, t = orbit_poses(a.poses)
        capture_to_folder(cam, folder, light, R, t, [[0.25, 1.0]] * a.poses, durable=False)
        print(f"capture: {a.poses} poses in {time.perf_counter() - t0:.1f} s -> {folder}")
    params = {"texels": [64, 64], "max_rms_mm": 0.5, **({"edge": a.edge} if a.edge else {}),
              **({"edge_margin_px": a.margin} if a.margin is not None else {}),
              **({"edge_min_weight": a.min_weight} if a.min_weight is not None else {})}
    edge = "-".join(f"{k}{v}" for k, v in params.items() if k.startswith("edge"))
    name = f"edge-{a.poses}{tag}-{edge or 'default'}"
    g = work / f"{name}.yaml"
    g.write_text("\n".join([
        f"name: {name}", f"store: {work / name}", "nodes:",
        f"  capture: {{kind: Capture, plugin: folder, params: {{path: '{folder}'}}}}",
        f"  register: {{kind: Register, plugin: aruco, in: {{capture: capture}}, params: {json.dumps(params)}}}",
        "  reflectance: {kind: Reflectance, in: {stack: register}}"]) + "\n")
    t0 = time.perf_counter()
    run_graph(str(g))
    print(f"register + reflectance: {time.perf_counter() - t0:.1f} s")
    fr = open_artifact(str(work / name / "reflectance"))
    f, valid = fr.read("f_r"), fr.read("valid")
    V, U, P = valid.shape
    truth = cam.reference_f_r((U, V), fr.read("light_pos"), fr.read("camera_pos"))
    ring = rings(V, U)
    n = valid.sum(axis=2)
    rel = np.abs(f[..., 1] / np.where(truth[..., 1] > 0, truth[..., 1], np.nan) - 1)
    out = {"poses": int(P), "unsampled": float((n == 0).mean()), "unsampled_texels": int((n == 0).sum())}
    for label, sel in (("ring0", ring == 0), ("ring1", ring == 1), ("ring2", ring == 2), ("interior", ring >= 3)):
        vs = valid & sel[..., None]
        out[f"{label}_texels"] = int(sel.sum())
        out[label] = int((n[sel] == 0).sum())
        out[f"valid_per_texel_{label}"] = round(float(n[sel].mean()), 2)
        out[f"err_{label}"] = round(float(np.nanmedian(rel[vs])), 4) if vs.any() else float("nan")
        out[f"err_p90_{label}"] = round(float(np.nanpercentile(rel[vs], 90)), 4) if vs.any() else float("nan")
        signed = f[..., 1] / np.where(truth[..., 1] > 0, truth[..., 1], np.nan) - 1
        out[f"bias_{label}"] = round(float(np.nanmedian(signed[vs])), 4) if vs.any() else float("nan")
    print(json.dumps(out, indent=1))
    print("edge_texels: " + " ".join(f"{k}={out[k]}" for k in (
        "unsampled", "ring0", "ring1", "ring2", "interior", "err_ring0", "err_ring1", "err_interior",
        "err_p90_ring0", "err_p90_interior")))
    return out


if __name__ == "__main__":
    main()
