"""Materials in and out: conversion errors and times of every import and export path, in one line.

Runs the four measurements, each a script of its own that can also be run alone:

- ``interchange_gltf.py``: any model refitted to glTF's GGX, exported, validated, read back and rendered;
- ``interchange_export.py``: EXR set, MaterialX, USD and Mitsuba exports; Mitsuba's render against ``cpu``;
- ``interchange_viewer.py``: the WebGL2 viewer in headless chromium against the ``gl`` renderer;
- ``interchange_merl.py``: a MERL-format file read, rendered, and fitted by Lafortune lobes;
- ``interchange_roundtrip.py``: the glTF export rendered by three.js and the Mitsuba export by Mitsuba 3, each
  against ``cpu``, on the README demo's fit (glossy) and a rough one, and the demo's exported glTF roughness.

Last line: ``interchange: gltf_conversion_rel_err=... mitsuba_vs_cpu_rel_err=... viewer_vs_gl_rel_err=...
merl_fit_rel_err=... glossy_gltf_rel_err=... glossy_mitsuba_rel_err=... rough_gltf_rel_err=...
rough_mitsuba_rel_err=... gltf_roughness_p50=... gltf_roughness_p99=... usd_roughness_p50=...
usd_clearcoat_roughness_p50=... usd_conv_err_p50=... glossy_gltf_from_samples_rel_err=...
rough_gltf_from_samples_rel_err=...`` plus each script's other figures
(prefixed by the script's name).  ``--quick`` passes on.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCRIPTS = {"gltf": "interchange_gltf.py", "export": "interchange_export.py", "viewer": "interchange_viewer.py",
           "merl": "interchange_merl.py", "roundtrip": "interchange_roundtrip.py"}
HEADLINE = ("gltf_conversion_rel_err", "mitsuba_vs_cpu_rel_err", "viewer_vs_gl_rel_err", "merl_fit_rel_err",
            "glossy_gltf_rel_err", "glossy_mitsuba_rel_err", "rough_gltf_rel_err", "rough_mitsuba_rel_err",
            "gltf_roughness_p50", "gltf_roughness_p99", "usd_roughness_p50", "usd_clearcoat_roughness_p50",
            "usd_conv_err_p50", "glossy_gltf_from_samples_rel_err", "rough_gltf_from_samples_rel_err")


def figures(line: str) -> dict[str, str]:
    """``name: k=v k=v`` -> ``{k: v}``."""
    return dict(kv.split("=", 1) for kv in line.split(":", 1)[1].split())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="each script's quick size (about a minute each)")
    ap.add_argument("--docs", action="store_true", help="accepted for `sbrdf bench`: the docs' images come from the tests")
    args = ap.parse_args()
    found: dict[str, str] = {}
    for key, script in SCRIPTS.items():
        t0 = time.perf_counter()
        cmd = [sys.executable, str(HERE / script)] + (["--quick"] if args.quick else [])
        run = subprocess.run(cmd, capture_output=True, text=True)
        lines = [ln for ln in run.stdout.splitlines() if ln.strip()]
        if run.returncode or not lines:
            print(f"{script} failed ({run.returncode}):\n{run.stderr[-2000:]}", file=sys.stderr)
            return 1
        print(f"{lines[-1]}   ({time.perf_counter() - t0:.0f} s)", flush=True)
        for k, v in figures(lines[-1]).items():
            found[k if k in HEADLINE else f"{key}_{k}"] = v
    head = " ".join(f"{k}={found.get(k, 'nan')}" for k in HEADLINE)
    rest = " ".join(f"{k}={v}" for k, v in found.items() if k not in HEADLINE)
    print(f"interchange: {head} {rest}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
