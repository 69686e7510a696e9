"""MERL import: read time, a Lafortune fit's error against the table, the tabulated model's render error.

The graph of ``graphs/merl-fit.yaml`` (``MerlFromModel`` writes a full-size
90 × 90 × 180 MERL file from a GGX Cook–Torrance material, ``MeasuredBRDF``
reads it back and samples 32 × 256 Fibonacci pairs up to 85° with the
trilinear lookup, ``Fit`` lm fits a 2-lobe Lafortune) is run into a
temporary store (``--quick``: 16 × 128 pairs).  Then:

- ``merl_fit_rel_err``: relative RMS, sqrt(Σ (f_fit − f_table)²) / sqrt(Σ f_table²) over RGB, of the fitted
  Lafortune against the table (``merl`` model, trilinear) at 4096 held-out direction pairs (uniform over the
  cap θ ≤ 85°, seeded, none of them fitted; ``--quick``: 1024).  f_r itself: the few grazing pairs where
  GGX with Fresnel reaches 8 sr⁻¹ dominate it, and Lafortune's cosine lobes cannot follow them; also printed
  (not on the last line): the same with both sides weighted by cos θ_i cos θ_o (reflected radiance under
  unit irradiance, the weighting fits of MERL data are usually judged by);
- ``merl_render_rel_err``: relative RMS over the lit pixels of the ``cpu`` image of a sphere made of the
  ``merl`` model against the image of the analytic Cook–Torrance the file was made from (160 × 120 pixels,
  one directional light; ``--quick``: 80 × 60);
- ``import_s``: median wall time of reading the 35 MB file (``read_merl``, 3 reads);
  ``sample_s``: MeasuredBRDF's read-and-sample time.

Also printed: the Fit node's own training and held-out RMS relative to the samples' RMS.  Last line:

    interchange_merl: merl_fit_rel_err=... merl_render_rel_err=... import_s=...
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "plugins"))


def held_out_pairs(n: int, max_theta_deg: float = 85.0, seed: int = 123) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    cap = 1 - np.cos(np.radians(max_theta_deg))

    def draw():
        z = 1 - rng.uniform(0, cap, n)
        phi = rng.uniform(0, 2 * np.pi, n)
        r = np.sqrt(np.clip(1 - z * z, 0, None))
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)

    return draw(), draw()


def render_error(registry, path: Path, resolution, params: dict, cfg: dict) -> float:
    from sbrdf_lib.scene import load_scene
    from sbrdf_render import materials as mat
    from sbrdf_render.cpu import render_scene

    def image(material: str) -> np.ndarray:
        text = (f"camera: {{position: [0.0, -1.6, 1.2], look_at: [0, 0, 0], fov_deg: 50, resolution: {list(resolution)}}}\n"
                f"materials: {{m: {material}}}\n"
                "objects: [{shape: sphere, radius: 0.6, material: m}]\n"
                "lights: [{type: directional, direction: [0.5, -0.3, 1.0], irradiance: [1, 1, 1]}]\nantialias: 1\n")
        scene = load_scene(text, registry=registry)
        img, _ = render_scene(scene, mat.resolve(scene, None, registry), registry=registry)
        return np.asarray(img, np.float64)

    p = ", ".join(f"{k}: {v}" for k, v in params.items())
    a = image(f"{{model: cook-torrance, model_params: {cfg}, params: {{{p}}}}}".replace("'", ""))
    m = image(f"{{model: merl, model_params: {{path: '{path}'}}, params: {{scale: [1, 1, 1]}}}}")
    lit = a.sum(axis=-1) > 1e-4 * a.max()
    return float(np.sqrt(np.mean((m[lit] - a[lit]) ** 2)) / np.sqrt(np.mean(a[lit] ** 2)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer samples and pixels (CI)")
    args = ap.parse_args()

    import yaml

    from sbrdf_core.registry import Registry
    from sbrdf_core.runner import run_graph
    from sbrdf_core.store import open_artifact
    from sbrdf_measured.merl import read_merl

    registry = Registry(extra=["sbrdf_measured"])
    graph = yaml.safe_load((ROOT / "graphs" / "merl-fit.yaml").read_text())
    if args.quick:
        graph["nodes"]["samples"]["params"].update(incident=16, exitant=128)
    with tempfile.TemporaryDirectory(prefix="merl-bench-") as tmp_name:
        tmp = Path(tmp_name)
        graph.pop("store", None)
        (tmp / "graph.yaml").write_text(yaml.safe_dump(graph))
        t0 = time.perf_counter()
        run_graph(str(tmp / "graph.yaml"), store=str(tmp / "store"), registry=registry, scheduler="threads")
        graph_s = time.perf_counter() - t0
        merl = open_artifact(str(tmp / "store" / "merl"))
        path = Path(merl.attrs["path"])
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            read_merl(path)
            times.append(time.perf_counter() - t0)
        import_s = float(np.median(times))
        samples = open_artifact(str(tmp / "store" / "samples"))
        fit = open_artifact(str(tmp / "store" / "fit"))
        valid = samples.read("valid")[0, 0]
        f = samples.read("f_r")[0, 0][valid].astype(np.float64)
        scale = float(np.sqrt(np.mean(f ** 2)))
        rms, held = float(fit.read("rms")[0, 0]), float(fit.read("rms_holdout")[0, 0])

        model = registry.create("brdf-model", fit.attrs["model"], dict(fit.attrs["model_config"]))
        params = {p.name: fit.read(f"params/{p.name}").reshape(1, -1).astype(np.float64) for p in model.parameters}
        table = registry.create("brdf-model", "merl", {"path": str(path)})
        wi, wo = held_out_pairs(1024 if args.quick else 4096)
        f_table = table.eval({"scale": np.ones((1, 3))}, wi[None], wo[None])
        f_fit = model.eval(params, wi[None], wo[None])
        fit_err = float(np.sqrt(np.sum((f_fit - f_table) ** 2)) / np.sqrt(np.sum(f_table ** 2)))
        cos = (wi[:, 2] * wo[:, 2])[None, :, None]
        fit_err_cos = float(np.sqrt(np.sum(((f_fit - f_table) * cos) ** 2)) / np.sqrt(np.sum((f_table * cos) ** 2)))

        node = graph["nodes"]["merl"]["params"]
        render_err = render_error(registry, path, (80, 60) if args.quick else (160, 120), node["params"],
                                  node["model_params"])
        print(f"graph (MerlFromModel -> MeasuredBRDF -> Fit lm lafortune): {graph_s:.2f} s; samples "
              f"{int(valid.sum())} valid; fit flags {int(fit.read('flags')[0, 0])}; training RMS / sample RMS "
              f"{rms / scale:.4f}, held-out (Fit's 10 %) {held / scale:.4f}", flush=True)
        print(f"held-out relative RMS of the fit: f_r {fit_err:.4f}, f_r cos_i cos_o {fit_err_cos:.4f}", flush=True)
        print(f"MeasuredBRDF read+sample {samples.attrs['measured']['import_s']:.3f} s; file {path.stat().st_size} "
              f"bytes", flush=True)
        print(f"interchange_merl: merl_fit_rel_err={fit_err:.4f} merl_render_rel_err={render_err:.4f} "
              f"import_s={import_s:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
