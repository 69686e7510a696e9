"""Fidelity of fitted materials at directions the fit never saw.

What it measures
----------------
Virtual captures, registration included, of spatially varying materials whose
truth is one BRDF model, fitted by *other* models with the ``lm`` fitter's
default parameters (only ``model``/``model_params`` are set: what a new user
gets), then scored against the truth at direction pairs that were not in the
capture.

Materials (truth parameter maps written as a ``ParamMaps`` artifact and
photographed by the ``virtual-camera`` device through its ``param_maps``
parameter; the camera supports per-texel maps of any model, so no change to it
was needed).  Both are split into three vertical bands of the sample, the
parameters varying smoothly inside each band (``sbrdf_capture.synthetic.pattern``):

``ct`` truth: Cook–Torrance, GGX D
    band 0 (u < 1/3) rough dielectric: α 0.25–0.5, F0 0.02–0.08, ρ_d 0.05–0.25;
    band 1 glossy metal: α 0.08–0.18, F0 0.5–0.95, ρ_d 0.01–0.04;
    band 2 **near-mirror**: α 0.02–0.035, F0 0.6–0.95, ρ_d 0.02–0.08.
``laf`` truth: Lafortune, 2 lobes (forward + back-scatter)
    band 0 broad: n₁ 4–15; band 1 off-specular (C_z = 0.97 |C_xy|: the lobe grows toward grazing): n₁ 20–80;
    band 2 **near-mirror**: n₁ 800–2500; lobe 2 C = (0.9, 0.9, 1), n₂ 2–6, ρ_s,₂ 0.05–0.2 everywhere.

``regions`` truth: ggx-anisotropic, four **uniform** quadrants (:data:`REGIONS`): plastic, gold, matte and
    brushed metal; fitted (orbit scan) by every model a user would pick (:data:`REGION_FITS`) for the
    spatial figures below.

Scans (each a ``virtual-camera`` capture folder -> ``folder`` Capture -> ``aruco``
Register -> Reflectance, exactly the path of ``graphs/virtual-scan.yaml``;
effects falloff, blur, motor_error, noise; one linear EXR exposure per pose):

``orbit``    ``orbit_poses`` (camera θ ≤ 50°, light θ ≤ 65°, Fibonacci spirals);
``grazing``  the **grazing-heavy** scan: camera θ 40–68°, light θ 62–82°.  A flat sample under one
             pose list gives every texel (nearly) the same directions, so a region with its own
             sampling is a second scan of the ``ct`` material rather than a band of it.

Fits (``Fit`` / ``lm``, defaults): ``laf1`` = Lafortune 1 lobe, ``laf2`` = 2 lobes, ``ward`` = Ward,
each of the ``ct`` truth on both scans (pooled); ``ct`` = Cook–Torrance GGX of the ``laf`` truth (orbit).

Metrics
-------
Scoring pairs, per texel, seeded and the same for every fit: ``PAIRS_RANDOM`` pairs with ω_i, ω_o
independently uniform in solid angle over θ ≤ 85°, plus ``PAIRS_MIRROR`` mirror pairs
(ω_o = mirror of ω_i, θ_i uniform in solid angle ≤ 85°).  None coincides with a captured pair.

- ``X_median``, ``X_p90``: median and 90th percentile, pooled over **all texels of the sample ×
  scoring pairs**, of the relative luminance error ``|Y(f_fit) − Y(f_true)| / Y(f_true)``
  (Y = Rec. 709 weights of linear RGB; f_true > 0 everywhere since every truth has ρ_d ≥ 0.01 sr⁻¹,
  so no floor is needed).  Texels the fit left at model defaults count: that is what the user gets.
  ``X_p90_sampled`` (extra key) pools only texels with at least one valid sample, ``X_mirror_median``
  only their mirror pairs, ``X_p90_random`` only the random pairs (every texel).  The relative error of an underestimate saturates at 1: where a fit misses a
  peak it never sampled (the near-mirror band's mirror pairs) it scores ≈ 1, so mirror pairs are kept
  to one pair in eight lest they pin the p90 at 1.
- ``fireflies``: texels, summed over all fits with the default bounds, whose maximum luminance over the hemisphere exceeds
  10× the truth's maximum at that texel.  The maximum is taken over a dense set: the planes
  Δφ = 0 and Δφ = 180° (where an isotropic lobe peaks: Lafortune's x is linear in cos Δφ, and
  Cook–Torrance's and Ward's half vector is nearest the normal at Δφ = 180°)
  with θ_i, θ_o on a 2.5° grid up to 85° (mirror pairs included), the scoring pairs, and a
  0.25° refinement (±2.5°) around each texel's coarse argmax — for the fit and the truth alike.
  ``X_fireflies`` per fit (extra keys).
- ``X_median_ideal``, ``X_p90_ideal``, ``X_fireflies_ideal`` (extra keys): the same figures for the **ideal
  fit**: the same fit (the Fit node's kernel, ``lm`` defaults, the same bounds) of noise-free samples of the
  truth itself at ``IDEAL_PAIRS`` pairs per texel drawn as the scoring pairs are (θ ≤ 85°, one in eight a
  mirror pair; another seed; every ``IDEAL_STRIDE``-th texel in each direction), scored as the fits are.
  It shows what the model, its bounds and the fitter's objective leave when the capture is perfect and covers
  the whole scored range.  It is not a lower bound: a fit of a narrower capture may score better in the
  range it saw (it need not compromise with grazing directions it never sampled).  Variants of ``laf2``
  (:data:`IDEAL_EXTRA`): ``laf2_relative`` (``weighting: relative``, closer to the relative error scored),
  ``laf2_unbounded`` (``grazing_growth: 0``), ``laf2_free`` (no peak, growth or sharpness bound, relative
  weighting).
- ``unsampled``: largest over the fits of the fraction of the sample's texels whose ``samples`` map
  (Fit node) is 0.
- ``render_max``: maximum pixel (any channel, linear) of a ``cpu`` Render of the ``laf2`` fit
  (orbit scan) in ``scenes/objects.yaml`` at a small resolution.

- ``X_spatial_cv`` (``regions`` fits): per quadrant, the median over the scoring pairs of the coefficient of
  variation of the fitted luminance f_r across the quadrant's texels (those at least :data:`REGION_MARGIN`
  from its edge); the largest over the quadrants.  ``noise_cv``: the same for the noise floor, the generating
  model fitted through the Fit node's own tile kernel (its held-out split and bounds) started from the truth.
  ``spatial_cv_max``: the largest over the fits.
- ``X_specks``: texels of a quadrant whose value in one of :data:`SPECK_RENDERS` departs from its 3×3
  neighbourhood's median by more than 4× the neighbourhood's spread (:func:`sbrdf_core.coherence.specks`);
  ``noise_specks`` for the floor; ``specks``: their sum over the fits.  ``X_regions_median``: the median
  relative error at the scoring pairs.
- ``--coherence MODE`` runs every Fit node with that ``coherence`` (``none``, ``neighbours``, ``pyramid``,
  ``basis``: the Fit node's choices): the paired comparison.

Sizes: full = 64×64 texels, 640×480 images, 90 orbit + 60 grazing poses (a few minutes on
2 cores); ``--quick`` = 32×32 texels, 480×360 images, 40 + 30 poses (about a minute).

Run::

    python benchmarks/fidelity.py [--quick] [--keep DIR]

Materials, captures and fits are written to a temporary folder (kept in ``DIR`` with ``--keep``).
A second run into the same ``DIR`` reuses its capture folders and the Runner's cached nodes, whose
tokens do not change with the code: compare code versions in fresh folders.
Last line::

    fidelity: laf1_median=... laf1_p90=... laf2_median=... laf2_p90=... ct_median=... ct_p90=...
    fireflies=... unsampled=... render_max=... ward_median=... ward_p90=... X_p90_sampled=...
    X_mirror_median=... X_p90_random=... X_fireflies=... X_s=...
    (X = laf1, laf2, ward, ct, ct_fr; X_s = Fit node wall time, s)

``ct_fr`` is ``ct`` fitted with ``microfacet_peak: f_r`` (the peak bound on f_r, as for Lafortune, instead of on
f_r·cos θ_i·cos θ_o): its keys show what forbidding Cook–Torrance's rise toward grazing costs where it was measured.
It is left out of the ``fireflies`` sum, which counts what a user gets with the defaults.

Progress, per-scan figures, per-band medians and the first firefly texels (v, u, band, valid samples,
fit max / truth max) go to stderr.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
LUMA = np.array([0.2126, 0.7152, 0.0722])
MAX_THETA = 85.0
PAIRS_RANDOM, PAIRS_MIRROR = 112, 16
SIZE_MM = (100.0, 100.0)
EFFECTS = ["falloff", "blur", "motor_error", "noise"]
INTENSITY = 1.5e5

FULL: dict[str, Any] = {"texels": 64, "width": 640, "height": 480, "focal": 900.0, "orbit": 90, "grazing": 60, "render": [320, 240]}
QUICK: dict[str, Any] = {"texels": 32, "width": 480, "height": 360, "focal": 675.0, "orbit": 40, "grazing": 30, "render": [160, 120]}

#: fit name -> (truth material, scans, model, model_params)
FITS: dict[str, tuple[str, tuple[str, ...], str, dict]] = {
    "laf1": ("ct", ("orbit", "grazing"), "lafortune", {"lobes": 1}),
    "laf2": ("ct", ("orbit", "grazing"), "lafortune", {"lobes": 2}),
    "ward": ("ct", ("orbit", "grazing"), "ward", {}),
    "ct": ("laf", ("orbit",), "cook-torrance", {"distribution": "ggx"}),
    "ct_fr": ("laf", ("orbit",), "cook-torrance", {"distribution": "ggx"}),
}
#: Fit node parameters of a fit beyond the defaults: ``ct_fr`` is ``ct`` with its peak bound on f_r itself
#: (``microfacet_peak: f_r``), the trade-off of fireflies against accuracy.  Extra keys only.
NODE_PARAMS = {"ct_fr": {"microfacet_peak": "f_r"}}
TRUTH: dict[str, tuple[str, dict]] = {"ct": ("cook-torrance", {"distribution": "ggx"}), "laf": ("lafortune", {"lobes": 2}),
         "regions": ("ggx-anisotropic", {})}
#: Fits of the ``regions`` material (orbit scan), every model a user would pick: name -> (model, model_params).
REGION_FITS: dict[str, tuple[str, dict]] = {"laf1": ("lafortune", {"lobes": 1}), "laf2": ("lafortune", {"lobes": 2}), "ward": ("ward", {}),
               "ct": ("cook-torrance", {"distribution": "ggx"}), "ggxa": ("ggx-anisotropic", {})}
#: The ``regions`` material's quadrants (v half, u half): plastic, gold, matte, brushed metal (ggx-anisotropic).
REGIONS = {(0, 0): {"rho_d": (0.25, 0.08, 0.05), "f0": (0.04,) * 3, "alpha_t": 0.12, "alpha_b": 0.12, "phi": 0.0},
           (0, 1): {"rho_d": (0.01,) * 3, "f0": (0.95, 0.7, 0.3), "alpha_t": 0.2, "alpha_b": 0.2, "phi": 0.0},
           (1, 0): {"rho_d": (0.2, 0.25, 0.3), "f0": (0.03,) * 3, "alpha_t": 0.6, "alpha_b": 0.6, "phi": 0.0},
           (1, 1): {"rho_d": (0.02,) * 3, "f0": (0.9,) * 3, "alpha_t": 0.08, "alpha_b": 0.35, "phi": 0.5}}
#: Texels from a quadrant's edge that its spatial figures leave out: the camera's blur and registration mix
#: the two materials of a boundary over about a texel.
REGION_MARGIN = 2
#: The "renders" specks are counted in, (θ_i, θ_o) in degrees on the plane φ_i = 0, φ_o = 180°: the view from
#: above with the light at 15–60° (the ``preview`` renderer's set-up), and two mirror pairs.
SPECK_RENDERS = ((15, 0), (30, 0), (45, 0), (60, 0), (30, 30), (45, 45))


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------
# truth materials
# ---------------------------------------------------------------------------


def _bands(n: int, k: int, c: int, ranges) -> np.ndarray:
    """(n, n) map: per vertical band b of three, ranges[b] = (lo, hi) spanned by a smooth pattern."""
    from sbrdf_capture.synthetic import pattern

    p = pattern(n, n, k, c)
    band = np.minimum((np.arange(n) * 3) // n, 2)[None, :].repeat(n, 0)
    lo = np.choose(band, [r[0] for r in ranges])
    hi = np.choose(band, [r[1] for r in ranges])
    return lo + (hi - lo) * p


def truth_maps(kind: str, n: int) -> dict[str, np.ndarray]:
    """Parameter maps ``name -> (V, U, C)`` of the truth material ``kind``."""
    def rgb(k, ranges):
        return np.stack([_bands(n, k, c, ranges) for c in range(3)], axis=-1)

    def one(k, ranges):
        return _bands(n, k, 0, ranges)[..., None]

    if kind == "regions":
        half = (np.arange(n) * 2) // n
        maps = {}
        for name in REGIONS[(0, 0)]:
            stack = [np.broadcast_to(np.atleast_1d(np.asarray(REGIONS[(a, b)][name], np.float64)), (n, n, 3 if name in
                     ("rho_d", "f0") else 1)) for a in (0, 1) for b in (0, 1)]
            which = (half[:, None] * 2 + half[None, :])[..., None]
            maps[name] = np.choose(np.broadcast_to(which, stack[0].shape), stack)
        return maps
    if kind == "ct":
        return {"rho_d": rgb(0, [(0.05, 0.25), (0.01, 0.04), (0.02, 0.08)]),
                "f0": rgb(1, [(0.02, 0.08), (0.5, 0.95), (0.6, 0.95)]),
                "alpha": one(2, [(0.25, 0.5), (0.08, 0.18), (0.02, 0.035)])}
    n1 = one(3, [(4.0, 15.0), (20.0, 80.0), (800.0, 2500.0)])
    # Peak lobe value ≈ albedo·(n+2)/(2π): keep each band's lobe albedo plausible (≤ ~0.6).
    albedo = one(4, [(0.3, 0.6), (0.3, 0.6), (0.4, 0.6)])
    tint = rgb(5, [(0.7, 1.0)] * 3)
    cz = np.ones((n, n, 1))
    cz1 = np.where(np.arange(n)[None, :, None] * 3 // n == 1, 0.97, 1.0) * np.ones((n, n, 1))
    return {"rho_d": rgb(6, [(0.03, 0.2), (0.02, 0.1), (0.01, 0.05)]),
            "rho_s_1": albedo * (n1 + 2) / (2 * np.pi) * tint, "c_xy_1": -np.ones((n, n, 1)), "c_z_1": cz1, "exponent_1": n1,
            "rho_s_2": rgb(7, [(0.05, 0.2)] * 3), "c_xy_2": np.full((n, n, 1), 0.9), "c_z_2": cz.copy(),
            "exponent_2": one(8, [(2.0, 6.0)] * 3)}


def write_param_maps(url: str, model, model_config: dict, maps: dict[str, np.ndarray]) -> None:
    """A minimal complete ParamMaps artifact (what the virtual camera's ``param_maps`` reads)."""
    import zarr

    V, U = next(iter(maps.values())).shape[:2]
    g = zarr.open_group(store=url, mode="w")
    for p in model.parameters:
        a = np.asarray(maps[p.name], np.float32)
        g.create_array(f"params/{p.name}", shape=a.shape, dtype="float32")[...] = a
    g.attrs.update({"kind": "ParamMaps", "version": 1, "complete": True, "token": "fidelity-truth", "model": model.name,
                    "model_config": model_config, "parameters": model.describe(), "texels": [U, V],
                    "size_mm": list(SIZE_MM), "fitter": None, "provenance": {"made_by": "benchmarks/fidelity.py"}})


# ---------------------------------------------------------------------------
# captures
# ---------------------------------------------------------------------------


def band_fibonacci(n: int, lo_deg: float, hi_deg: float, offset: float = 0.0) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = np.cos(np.radians(lo_deg)) - (np.cos(np.radians(lo_deg)) - np.cos(np.radians(hi_deg))) * i / n
    phi = np.pi * (3 - np.sqrt(5)) * i + offset
    s = np.sqrt(np.clip(1 - z * z, 0, None))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def poses(scan: str, n: int):
    from sbrdf_capture.photograph import orbit_poses
    from sbrdf_core.geometry import look_at

    if scan == "orbit":
        return orbit_poses(n)
    cams = band_fibonacci(n, 40.0, 68.0, offset=2.0) * 350.0
    lights = band_fibonacci(n, 62.0, 82.0)[::-1] * 450.0
    Rt = [look_at(c) for c in cams]
    return lights, np.stack([R for R, _ in Rt]), np.stack([t for _, t in Rt])


def capture(folder: Path, truth_url: str, scan: str, size: dict, seed: int) -> None:
    from sbrdf_capture.photograph import capture_to_folder
    from sbrdf_core.registry import default_registry

    reg = default_registry()
    cam = reg.create("device", "virtual-camera", {
        "width": size["width"], "height": size["height"], "focal_px": size["focal"], "param_maps": truth_url,
        "effects": EFFECTS, "intensity": INTENSITY, "seed": seed})
    cam.bind(reg)
    light, R, t = poses(scan, size[scan])
    capture_to_folder(cam, folder, light, R, t, 1.0, durable=False)


# ---------------------------------------------------------------------------
# the graph
# ---------------------------------------------------------------------------


def graph_text(scans: dict[str, Path], texels: int, scene: Path, common: dict | None = None) -> str:
    """The benchmark's graph; ``common``: Fit node parameters of every fit (``--coherence``)."""
    common = common or {}
    lines = ["name: fidelity-benchmark", "store: ./store", "nodes:"]
    for key, folder in scans.items():
        lines += [f"  cap_{key}: {{kind: Capture, plugin: folder, params: {{path: {json.dumps(str(folder))}}}}}",
                  f"  reg_{key}: {{kind: Register, plugin: aruco, in: {{capture: cap_{key}}}, "
                  f"params: {{texels: [{texels}, {texels}], max_rms_mm: 0.5}}}}",
                  f"  refl_{key}: {{kind: Reflectance, in: {{stack: reg_{key}}}}}"]
    for name, (truth, scan_list, model, mp) in FITS.items():
        for scan in scan_list:
            params = {"model": model, "model_params": mp, **NODE_PARAMS.get(name, {}), **common}
            lines.append(f"  {name}_{scan}: {{kind: Fit, plugin: lm, in: {{samples: refl_{truth}_{scan}}}, "
                         f"params: {json.dumps(params)}}}")
    for name, (model, mp) in REGION_FITS.items():
        lines.append(f"  regions_{name}: {{kind: Fit, plugin: lm, in: {{samples: refl_regions_orbit}}, "
                     f"params: {json.dumps({'model': model, 'model_params': mp, **common})}}}")
    lines.append(f"  render: {{kind: Render, plugin: cpu, in: {{material: laf2_orbit}}, "
                 f"params: {{scene: {json.dumps(str(scene))}}}}}")
    return "\n".join(lines) + "\n"


def write_scene(path: Path, resolution) -> None:
    import yaml

    scene = yaml.safe_load((ROOT / "scenes" / "objects.yaml").read_text())
    scene["camera"]["resolution"] = list(resolution)
    path.write_text(yaml.safe_dump(scene))


# ---------------------------------------------------------------------------
# scoring
# ---------------------------------------------------------------------------


def _uniform_dirs(rng, shape) -> np.ndarray:
    z = 1 - rng.random(shape) * (1 - np.cos(np.radians(MAX_THETA)))
    phi = rng.random(shape) * 2 * np.pi
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def scoring_pairs(T: int, seed: int = 20) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    wi = _uniform_dirs(rng, (T, PAIRS_RANDOM + PAIRS_MIRROR))
    wo = _uniform_dirs(rng, (T, PAIRS_RANDOM + PAIRS_MIRROR))
    m = wi[:, PAIRS_RANDOM:]
    wo[:, PAIRS_RANDOM:] = np.stack([-m[..., 0], -m[..., 1], m[..., 2]], axis=-1)
    return wi, wo


def _plane_dirs(ti, to, plane):
    """ω_i in the xz plane at θ_i, ω_o at θ_o with Δφ = 0 (plane 0) or 180° (plane 1); radians, broadcast."""
    sgn = np.where(plane == 1, -1.0, 1.0)
    wi = np.stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)], axis=-1)
    wo = np.stack([sgn * np.sin(to), np.zeros_like(to), np.cos(to)], axis=-1)
    return wi, wo


def _lum(model, params, wi, wo) -> np.ndarray:
    return np.einsum("tsc,c->ts", model.eval(params, wi, wo), LUMA)


def hemisphere_max(model, params, wi_s, wo_s) -> np.ndarray:
    """Per-texel maximum luminance over the dense set described in the module docstring, ``(T,)``."""
    T = wi_s.shape[0]
    g = np.radians(np.arange(0.0, MAX_THETA + 1e-9, 2.5))
    ti, to, pl = np.meshgrid(g, g, np.array([0, 1]), indexing="ij")
    ti, to, pl = ti.ravel(), to.ravel(), pl.ravel()
    wi, wo = _plane_dirs(ti, to, pl)
    y = _lum(model, params, np.broadcast_to(wi, (T,) + wi.shape), np.broadcast_to(wo, (T,) + wo.shape))
    best = y.argmax(axis=1)
    out = np.maximum(y.max(axis=1), _lum(model, params, wi_s, wo_s).max(axis=1))
    d = np.radians(np.arange(-2.5, 2.5 + 1e-9, 0.25))
    dti, dto = np.meshgrid(d, d, indexing="ij")
    lim = np.radians(MAX_THETA)
    fti = np.clip(ti[best][:, None] + dti.ravel()[None], 0.0, lim)
    fto = np.clip(to[best][:, None] + dto.ravel()[None], 0.0, lim)
    wi, wo = _plane_dirs(fti, fto, np.broadcast_to(pl[best][:, None], fti.shape))
    return np.maximum(out, _lum(model, params, wi, wo).max(axis=1))


#: main at 9a90d69, before the held-out scoring and the bounds, this script at full size on the 2-core VM.
BEFORE_WEIGHTING = ("laf1 median 0.184 / p90 0.966, laf2 0.153 / 0.950, ward 0.131 / 0.850, ct 0.365 / 1.615; "
                    "fireflies 3325 (all ct)")
BASELINE = ("laf1 median 0.164 / p90 1.07, laf2 0.175 / 1.12, ward 0.210 / 1.09, ct 0.421 / 3.98; fireflies 4134 "
            "(laf1 152, laf2 249, ward 98, ct 3635); 9.9 % of texels unsampled; cpu render maximum 4.9e28")


def write_docs(rows, line: str, size: dict, wall_s: float, figures: dict) -> None:
    """The fidelity section of docs/accuracy-vs-time.md: error at unseen directions beside training and held-out RMS."""
    import datetime

    from report import machine, replace_section

    table = ["| fit | truth | scans | training RMS (sr⁻¹) | held-out RMS (sr⁻¹) | unseen median | unseen p90 | fireflies "
             "| ideal median | ideal p90 | Fit wall s |", "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, (truth, scans, model, mp), train, held, med, p90, ff, sec in rows:
        label = model + (f" {mp['lobes']} lobe" + ("s" if mp["lobes"] > 1 else "") if "lobes" in mp else "")
        table.append(f"| `{name}`: {label} | {TRUTH[truth][0]} | {', '.join(scans)} | {train:.4g} | {held:.4g} | "
                     f"{med:.3f} | {p90:.3f} | {ff} | {figures[f'{name}_median_ideal']:.3f} | "
                     f"{figures[f'{name}_p90_ideal']:.3f} | {sec:.1f} |")
    section = "\n".join([
        "<!-- fidelity:begin (generated by benchmarks/fidelity.py --docs; do not edit by hand) -->",
        "## Fidelity at unseen directions",
        "",
        f"Virtual-camera scans ({size['texels']}² texels, ArUco registration included) of a 3-band Cook–Torrance GGX "
        "material (rough, glossy, near-mirror; an orbit and a grazing-heavy pose list) fitted with `lm` defaults by "
        "Lafortune 1 and 2 lobes and Ward, and of a 3-band 2-lobe Lafortune material fitted by Cook–Torrance. "
        "*Training RMS* and *held-out RMS* are the Fit node's own (`rms`, `rms_holdout`: 10 % of each texel's samples "
        "held out); *unseen* is the relative luminance error against the truth at 128 seeded direction pairs per "
        "texel that no capture took (θ ≤ 85°, 1 in 8 a mirror pair), the figure the training RMS cannot show; "
        "fireflies are texels whose maximum over the hemisphere exceeds 10× the truth's there. `ct_fr` is `ct` with "
        "`microfacet_peak: f_r` (the peak bound on f_r itself), not counted in the line's `fireflies`. "
        f"*Ideal* is the same fit (the Fit node's kernel, `lm` defaults, the same bounds) of noise-free samples of "
        f"the truth itself at {IDEAL_PAIRS} pairs per texel over the whole scored range (one texel in "
        f"{IDEAL_STRIDE}×{IDEAL_STRIDE}), scored at the same kind of unseen pairs: what the model, its bounds and the fitter's objective "
        "leave with a perfect capture. It is not a lower bound: a fit of a narrower scan can score better where "
        "it need not compromise with directions it never saw. `laf2` ideal variants: "
        + ", ".join(f"{label} median {figures[f'{key}_median_ideal']:.3f} / p90 {figures[f'{key}_p90_ideal']:.3f}"
                    for key, label in (("laf2_relative", "`weighting: relative`"),
                                       ("laf2_unbounded", "`grazing_growth: 0`"),
                                       ("laf2_free", "no peak, growth or sharpness bound with relative weighting")))
        + ".",
        f"Machine: {machine()}. Date: {datetime.date.today()}. Whole script: {wall_s:.0f} s.",
        "",
        *table,
        "",
        f"`{line}`",
        "",
        f"At 9a90d69, before the held-out scoring and the bounds (same script, same data): {BASELINE}.",
        "",
        f"Before `weighting: shot-noise` became `lm`'s default (absolute least squares; same data, same "
        f"registration): {BEFORE_WEIGHTING}.",
        "<!-- fidelity:end -->",
        "",
    ])
    replace_section("fidelity", section)


def _load(url: str, reg):
    """``(model, {parameter: (V, U, C)})`` of a stored ParamMaps artifact, and the artifact."""
    from sbrdf_core.store import open_artifact

    art = open_artifact(url, kind="ParamMaps")
    model = reg.create("brdf-model", art.attrs["model"], dict(art.attrs.get("model_config", {})))
    return model, {p.name: np.asarray(art.read(f"params/{p.name}"), np.float64) for p in model.parameters}, art


def score(fit_url: str, truth_url: str) -> dict:
    """Relative luminance errors ``(T, S)``, firefly mask ``(T,)``, sample counts ``(T,)`` of one fit."""
    from sbrdf_core.registry import default_registry

    reg = default_registry()
    fit_model, fit_params, art = _load(fit_url, reg)
    out = score_params(fit_model, fit_params, *_load(truth_url, reg)[:2])
    out["samples"] = np.asarray(art.read("samples")).reshape(-1)
    out["flags"] = np.asarray(art.read("flags")).reshape(-1)
    return out


def score_params(fit_model, fit_params, truth_model, truth_params, chunk: int = 256) -> dict:
    """:func:`score` of parameter maps ``{name: (V, U, C)}`` in memory: ``rel``, ``fmax``, ``tmax``, ``firefly``."""
    V, U = next(iter(fit_params.values())).shape[:2]
    tv, tu = next(iter(truth_params.values())).shape[:2]
    if (tv, tu) != (V, U):
        raise RuntimeError(f"truth grid {tu}x{tv} differs from the fitted grid {U}x{V}")
    T = V * U
    flat = [{n: a.reshape(T, -1) for n, a in p.items()} for p in (fit_params, truth_params)]
    wi_all, wo_all = scoring_pairs(T)
    rel = np.empty(wi_all.shape[:2])
    fmax, tmax = np.empty(T), np.empty(T)
    for s in range(0, T, chunk):
        sl = slice(s, min(s + chunk, T))
        pf, pt = ({n: a[sl] for n, a in f.items()} for f in flat)
        wi, wo = wi_all[sl], wo_all[sl]
        yf, yt = _lum(fit_model, pf, wi, wo), _lum(truth_model, pt, wi, wo)
        rel[sl] = np.abs(yf - yt) / yt
        fmax[sl] = hemisphere_max(fit_model, pf, wi, wo)
        tmax[sl] = hemisphere_max(truth_model, pt, wi, wo)
    return {"rel": rel, "fmax": fmax, "tmax": tmax, "firefly": ~(fmax <= 10 * tmax), "grid": (V, U)}


#: Direction pairs of an ideal fit: shared by every texel, drawn as the scoring pairs are (θ ≤ 85°, one in
#: eight a mirror pair) but from another seed, so it is not fitted to the very pairs it is scored at.
IDEAL_PAIRS = 512
#: Every IDEAL_STRIDE-th texel in each direction gets an ideal fit (the truth maps vary smoothly inside their
#: bands, so a subsample has their distribution): the generic LM of Cook–Torrance and Ward costs about 20 ms
#: per texel at 512 pairs on this VM.
IDEAL_STRIDE = 2
#: Ideal fits beyond those of :data:`FITS`: name -> (fit, Fit node parameters, ``lm`` parameters), variants of
#: ``laf2`` that show what its 90th percentile owes to the bounds and to the fitter's objective.
IDEAL_EXTRA = {"laf2_relative": ("laf2", {}, {"weighting": "relative"}),
               "laf2_unbounded": ("laf2", {"grazing_growth": 0.0}, {}),
               "laf2_free": ("laf2", {"peak_factor": 0.0, "grazing_growth": 0.0, "resolve_sharpness": False},
                             {"weighting": "relative"})}


def ideal_fit(truth_url: str, model_name: str, model_params: dict, node_params: dict | None = None,
              fitter_params: dict | None = None) -> dict:
    """:func:`score_params` of the Fit node's tile kernel (``lm``) on noise-free, dense truth samples.

    The fit sees the truth itself at :data:`IDEAL_PAIRS` pairs per texel over the whole scored range, with no
    camera, registration or noise between, under the bounds ``node_params`` give the Fit node (no samples held
    out) and the ``lm`` parameters ``fitter_params``: the error the model, its bounds and the fitter's
    objective leave with a perfect capture.  Not a lower bound (see the module docstring).
    """
    from sbrdf_core.nodes.fit import FitOptions, fit_tile
    from sbrdf_core.registry import default_registry

    reg = default_registry()
    truth_model, truth_params, _ = _load(truth_url, reg)
    truth_params = {k: v[::IDEAL_STRIDE, ::IDEAL_STRIDE] for k, v in truth_params.items()}
    V, U = next(iter(truth_params.values())).shape[:2]
    wi, wo = scoring_pairs(IDEAL_PAIRS // 128, seed=21)  # rows of 112 random + 16 mirror pairs
    wi, wo = wi.reshape(1, -1, 3), wo.reshape(1, -1, 3)
    flat = {n: a.reshape(V * U, -1) for n, a in truth_params.items()}
    f = truth_model.eval(flat, np.broadcast_to(wi, (V * U,) + wi.shape[1:]), np.broadcast_to(wo, (V * U,) + wo.shape[1:]))
    model = reg.create("brdf-model", model_name, model_params)
    fitter = reg.create("fitter", "lm", {"model": model_name, "model_params": model_params, **(fitter_params or {})})
    far = 1e9  # mm: positions this far away give every texel the same ω_i, ω_o (to 1e-10)
    f, valid, options = f.reshape(V, U, -1, 3), np.ones((V, U, f.shape[1]), bool), FitOptions(holdout=0.0, **(node_params or {}))
    out = np.concatenate([fit_tile(f[v0:v0 + 16], valid[v0:v0 + 16], wi[0] * far, wo[0] * far, [U, V], SIZE_MM, fitter,
                                   model, options, block_info=[{"array-location": [(v0, min(v0 + 16, V)), (0, U)]}])
                          for v0 in range(0, V, 16)])  # row bands, as the node's tasks: bounded memory
    params = model.unpack(out[..., :model.size].reshape(V * U, -1).astype(np.float64))
    fit_params = {k: np.asarray(v).reshape(V, U, -1) for k, v in params.items()}
    return score_params(model, fit_params, truth_model, truth_params)


def region_interiors(n: int) -> np.ndarray:
    """``(V, U)`` region index of the ``regions`` material's texels, −1 within :data:`REGION_MARGIN` of an edge."""
    half = (np.arange(n) * 2) // n
    edge = np.minimum(np.arange(n) % (n // 2), (n // 2 - 1) - np.arange(n) % (n // 2))  # texels to the quadrant edge
    inside = (edge[:, None] >= REGION_MARGIN) & (edge[None, :] >= REGION_MARGIN)
    return np.where(inside, half[:, None] * 2 + half[None, :], -1)


def region_cvs(model, params: dict, region: np.ndarray) -> list[float]:
    """Per region (0..3) of parameter maps ``{name: (V, U, C)}``: the median over :func:`scoring_pairs` of the
    coefficient of variation of luminance f_r across the region's texels (:func:`spatial_cv` takes the largest)."""
    V, U = region.shape
    T = V * U
    flat = {k: v.reshape(T, -1) for k, v in params.items()}
    wi, wo = scoring_pairs(1, seed=30)
    y = _lum(model, flat, np.broadcast_to(wi, (T,) + wi.shape[1:]), np.broadcast_to(wo, (T,) + wo.shape[1:]))
    y = y.reshape(V, U, -1)
    cvs = []
    for r in range(4):
        vals = y[region == r]  # (texels, pairs)
        cvs.append(float(np.median(vals.std(axis=0) / np.maximum(np.abs(vals.mean(axis=0)), 1e-12))))
    return cvs


def spatial_cv(model, params: dict, region: np.ndarray) -> tuple[float, int]:
    """``(cv, specks)`` of parameter maps ``{name: (V, U, C)}``: the largest over regions of the median over
    :func:`scoring_pairs` (128 pairs, unseen) of the coefficient of variation of luminance f_r across the
    region's texels, and the texels that are specks (:func:`sbrdf_core.coherence.specks`) in any of
    :data:`SPECK_RENDERS`."""
    from sbrdf_core.coherence import specks

    V, U = region.shape
    T = V * U
    flat = {k: v.reshape(T, -1) for k, v in params.items()}

    def look(wi, wo):
        return _lum(model, flat, np.broadcast_to(wi, (T,) + wi.shape[1:]),
                    np.broadcast_to(wo, (T,) + wo.shape[1:])).reshape(V, U, -1)

    cvs = region_cvs(model, params, region)
    t_i, t_o = np.radians(np.array(SPECK_RENDERS, np.float64)).T
    wi = np.stack([np.sin(t_i), np.zeros_like(t_i), np.cos(t_i)], axis=-1)[None]
    wo = np.stack([-np.sin(t_o), np.zeros_like(t_o), np.cos(t_o)], axis=-1)[None]
    renders = look(wi, wo)
    speck = np.zeros((V, U), bool)
    for j in range(renders.shape[-1]):
        for r in range(4):
            speck |= specks(renders[..., j], uniform=region == r)
    return max(cvs), int(speck.sum())


def noise_floor_fit(graph, truth_url: str) -> dict:
    """The generating model (``ggx-anisotropic``) fitted to the ``regions`` capture's samples by the Fit node's
    own tile kernel (the same held-out split and bounds, ``coherence: none``), ``lm`` started from the truth
    itself: what the capture's noise and the node's bounds alone leave, no local minimum on the way."""
    from sbrdf_core.nodes.fit import FitOptions, fit_tile
    from sbrdf_core.registry import default_registry
    from sbrdf_core.store import open_artifact

    reg = default_registry()
    model, truth, _ = _load(truth_url, reg)
    refl = open_artifact(graph.url("refl_regions_orbit"))
    f_r, valid = np.asarray(refl.read("f_r"), np.float64), np.asarray(refl.read("valid"), bool)
    V, U = f_r.shape[:2]
    start = {k: v.reshape(V * U, -1) for k, v in truth.items()}
    lm = reg.create("fitter", "lm", {"model": model.name})

    class FromTruth:  # lm, started from the truth wherever it fits the whole grid
        model_name, model_config = model.name, dict[str, Any]()

        def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False, initial=None):
            if initial is None and f_r.shape[0] == V * U:
                initial = start
            return lm.fit(model, f_r, valid, wi, wo, limits=limits, rms=rms, usable=usable, initial=initial)

    out = fit_tile(f_r, valid[..., None], refl.read("light_pos"), refl.read("camera_pos"),
                   tuple(refl.attrs["texels"]), tuple(refl.attrs["size_mm"]), FromTruth(), model,
                   FitOptions(coherence="none"), block_info=[{"array-location": [(0, V), (0, U)]}])
    params = model.unpack(out[..., :model.size].reshape(V * U, -1).astype(np.float64))
    return {k: np.asarray(v).reshape(V, U, -1) for k, v in params.items()}


def spatial_figures(graph, report, truth_url: str) -> dict:
    """Per ``regions`` fit: ``X_spatial_cv``, ``X_specks``, ``X_regions_median`` (median relative error at unseen
    pairs); and ``noise_cv``, ``noise_specks`` of :func:`noise_floor_fit`."""
    from sbrdf_core.registry import default_registry

    reg = default_registry()
    truth_model, _, _ = _load(truth_url, reg)
    out: dict = {}
    region = None
    for name in REGION_FITS:
        node = f"regions_{name}"
        model, params, art = _load(graph.url(node), reg)
        region = region_interiors(params[next(iter(params))].shape[0]) if region is None else region
        out[f"{name}_spatial_cv"], out[f"{name}_specks"] = spatial_cv(model, params, region)
        out[f"{name}_regions_median"] = float(np.median(score(graph.url(node), truth_url)["rel"]))
        log(f"{node}: {report[node].wall_s:.1f} s, spatial cv {out[f'{name}_spatial_cv']:.4f}, "
            f"specks {out[f'{name}_specks']}, median {out[f'{name}_regions_median']:.4f}, "
            f"summary {art.attrs.get('summary', {}).get('texels_flagged', {})}")
    assert region is not None
    out["noise_cv"], out["noise_specks"] = spatial_cv(truth_model, noise_floor_fit(graph, truth_url), region)
    log(f"noise floor (ggx-anisotropic from the truth): spatial cv {out['noise_cv']:.4f}, specks {out['noise_specks']}")
    return out


def warm(workdir: Path) -> None:
    """Fit each model once on a tiny ``SampleModel`` grid, so JIT compilation is not charged to the first fit."""
    from sbrdf_core.graph import load_graph
    from sbrdf_core.registry import Registry
    from sbrdf_core.runner import Runner

    workdir.mkdir(parents=True, exist_ok=True)
    sample = {"model": "lafortune", "model_params": {"lobes": 2}, "texels": [8, 8], "poses": 50, "noise": 0.01,
              "seed": 0, "directions": "random", "max_theta_deg": 80.0}
    lines = ["name: fidelity-warm", "store: ./store", "nodes:", f"  samples: {{kind: SampleModel, params: {json.dumps(sample)}}}"]
    for name, (_, _, model, mp) in FITS.items():
        lines.append(f"  {name}: {{kind: Fit, plugin: lm, in: {{samples: samples}}, "
                     f"params: {json.dumps({'model': model, 'model_params': mp})}}}")
    (workdir / "graph.yaml").write_text("\n".join(lines) + "\n")
    reg = Registry()
    Runner(reg, progress=False).run(load_graph(workdir / "graph.yaml", reg))


# ---------------------------------------------------------------------------


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="32x32 texels, fewer poses and pixels (about a minute)")
    ap.add_argument("--keep", metavar="DIR", default=None, help="write materials, captures and fits here and keep them")
    ap.add_argument("--docs", action="store_true", help="rewrite the fidelity section of docs/accuracy-vs-time.md")
    from sbrdf_core.nodes.fit import FIT_PARAMS

    ap.add_argument("--coherence", choices=next(p.choices for p in FIT_PARAMS if p.name == "coherence"), default=None,
                    help="the Fit nodes' coherence (default: the node's own default), for a paired comparison")
    args = ap.parse_args(argv)
    size = QUICK if args.quick else FULL
    n = size["texels"]
    t_start = time.perf_counter()
    if args.keep:
        workdir = Path(args.keep).resolve()
        workdir.mkdir(parents=True, exist_ok=True)
    else:
        workdir = Path(tempfile.mkdtemp(prefix="sbrdf-fidelity-"))
    try:
        from sbrdf_core.graph import load_graph
        from sbrdf_core.registry import Registry, default_registry
        from sbrdf_core.runner import Runner
        from sbrdf_core.store import open_artifact

        reg0 = default_registry()
        truth_urls = {}
        for kind, (model_name, mp) in TRUTH.items():
            url = str(workdir / f"truth_{kind}")
            write_param_maps(url, reg0.create("brdf-model", model_name, mp), mp, truth_maps(kind, n))
            truth_urls[kind] = url
        scans = {}
        for k, (truth, scan) in enumerate((("ct", "orbit"), ("ct", "grazing"), ("laf", "orbit"),
                                           ("regions", "orbit"))):
            folder = workdir / f"capture_{truth}_{scan}"
            t0 = time.perf_counter()
            if not (folder / "capture.json").exists() or args.keep is None:
                capture(folder, truth_urls[truth], scan, size, seed=k)
            scans[f"{truth}_{scan}"] = folder
            log(f"capture {truth}/{scan}: {size[scan]} poses, {time.perf_counter() - t0:.1f} s")
        scene = workdir / "scene.yaml"
        write_scene(scene, size["render"])
        gpath = workdir / "graph.yaml"
        gpath.write_text(graph_text(scans, n, scene, {"coherence": args.coherence} if args.coherence else None))
        warm(workdir / "warm")  # import and JIT-compile the fitters' kernels off the clock
        reg = Registry()
        graph = load_graph(gpath, reg)
        t0 = time.perf_counter()
        report = Runner(reg, progress=False).run(graph)
        log(f"graph: {time.perf_counter() - t0:.1f} s")

        figures: dict[str, float] = {}
        unsampled, fireflies, seconds, rows = [], 0, {}, []
        for name, (truth, scan_list, _, _) in FITS.items():
            rels, sampled_rels, mirror_rels, random_rels, ff = [], [], [], [], 0
            seconds[name] = 0.0
            train_rms, held_rms = [], []
            for scan in scan_list:
                node = f"{name}_{scan}"
                seconds[name] += report[node].wall_s
                s = score(graph.url(node), truth_urls[truth])
                rels.append(s["rel"].ravel())
                sampled_rels.append(s["rel"][s["samples"] > 0].ravel())
                mirror_rels.append(s["rel"][s["samples"] > 0][:, PAIRS_RANDOM:].ravel())
                random_rels.append(s["rel"][:, :PAIRS_RANDOM].ravel())
                unsampled.append(float((s["samples"] == 0).mean()))
                bad = np.flatnonzero(s["firefly"])
                ff += bad.size
                V, U = s["grid"]
                where = ", ".join(f"(v={b // U},u={b % U},band={min(3 * (b % U) // U, 2)},n={s['samples'][b]},"
                                  f"max={s['fmax'][b]:.3g}/{s['tmax'][b]:.3g})" for b in bad[:8])
                summary = open_artifact(graph.url(node)).attrs.get("summary", {})
                train_rms.append(summary.get("rms_mean"))
                held_rms.append(summary.get("rms_holdout_mean"))
                log(f"{node}: {report[node].wall_s:.1f} s, median {np.median(s['rel']):.4f}, "
                    f"p90 {np.percentile(s['rel'], 90):.4f}, no samples {int((s['samples'] == 0).sum())}, "
                    f"fireflies {bad.size}{': ' + where if bad.size else ''}; flagged {summary.get('texels_flagged', {})}")
                per_band = [np.median(s["rel"].reshape(V, U, -1)[:, b * U // 3:(b + 1) * U // 3]) for b in range(3)]
                log("    median per band (0 rough, 1 glossy, 2 near-mirror): "
                    + " ".join(f"{x:.4f}" for x in per_band))
            rel = np.concatenate(rels)
            srel = np.concatenate(sampled_rels)
            figures[f"{name}_median"] = float(np.median(rel))
            figures[f"{name}_p90"] = float(np.percentile(rel, 90))
            figures[f"{name}_p90_sampled"] = float(np.percentile(srel, 90)) if srel.size else float("nan")
            mrel = np.concatenate(mirror_rels)
            figures[f"{name}_mirror_median"] = float(np.median(mrel)) if mrel.size else float("nan")
            figures[f"{name}_p90_random"] = float(np.percentile(np.concatenate(random_rels), 90))
            figures[f"{name}_fireflies"] = ff
            fireflies += 0 if name in NODE_PARAMS else ff
            mean = lambda xs: float(np.mean(xs)) if xs and None not in xs else float("nan")  # noqa: E731
            rows.append((name, FITS[name], mean(train_rms), mean(held_rms), figures[f"{name}_median"],
                         figures[f"{name}_p90"], ff, seconds[name]))
        for name, (base, extra_params, fitter_params) in [(k, (k, {}, {})) for k in FITS] + list(IDEAL_EXTRA.items()):
            truth, _, model_name, mp = FITS[base]
            t0 = time.perf_counter()
            fl = ideal_fit(truth_urls[truth], model_name, mp, {**NODE_PARAMS.get(base, {}), **extra_params}, fitter_params)
            figures[f"{name}_median_ideal"] = float(np.median(fl["rel"]))
            figures[f"{name}_p90_ideal"] = float(np.percentile(fl["rel"], 90))
            figures[f"{name}_fireflies_ideal"] = int(fl["firefly"].sum())
            log(f"ideal {name}: median {figures[f'{name}_median_ideal']:.4f}, p90 {figures[f'{name}_p90_ideal']:.4f}, "
                f"mirror median {np.median(fl['rel'][:, PAIRS_RANDOM:]):.4f}, "
                f"fireflies {figures[f'{name}_fireflies_ideal']} ({time.perf_counter() - t0:.1f} s)")
        spatial = spatial_figures(graph, report, truth_urls["regions"])
        figures.update(spatial)
        img = np.asarray(open_artifact(graph.url("render")).read("image"), np.float64)
        render_max = float(np.nanmax(img)) if np.isfinite(img).any() else float("inf")
        log(f"render: {report['render'].wall_s:.1f} s, max {render_max:.4g}, pixels > 1e6: {int((img > 1e6).any(-1).sum())}")
        log(f"total {time.perf_counter() - t_start:.1f} s; work in {workdir}")

        def g(x):
            return f"{x:.6g}"

        head = " ".join(f"{k}={g(figures[k])}" for k in
                        ("laf1_median", "laf1_p90", "laf2_median", "laf2_p90", "ct_median", "ct_p90"))
        extra = " ".join([f"{k}={g(figures[k])}" for k in ("ward_median", "ward_p90", "ct_fr_median", "ct_fr_p90")
                          if k in figures]
                         + [f"{k}_p90_sampled={g(figures[f'{k}_p90_sampled'])}" for k in FITS]
                         + [f"{k}_mirror_median={g(figures[f'{k}_mirror_median'])}" for k in FITS]
                         + [f"{k}_p90_random={g(figures[f'{k}_p90_random'])}" for k in FITS]
                         + [f"{k}_fireflies={figures[f'{k}_fireflies']}" for k in FITS]
                         + [f"{k}_s={seconds[k]:.2f}" for k in FITS]
                         + [f"{k}_{m}_ideal={g(figures[f'{k}_{m}_ideal'])}" for k in (*FITS, *IDEAL_EXTRA)
                            for m in ("median", "p90", "fireflies")])
        cv = " ".join(f"{k}_spatial_cv={g(spatial[f'{k}_spatial_cv'])}" for k in REGION_FITS)
        spatial_line = (f"spatial_cv_max={g(max(spatial[f'{k}_spatial_cv'] for k in REGION_FITS))} "
                        f"noise_cv={g(spatial['noise_cv'])} specks={sum(spatial[f'{k}_specks'] for k in REGION_FITS)} "
                        f"noise_specks={spatial['noise_specks']} {cv} "
                        + " ".join(f"{k}_specks={spatial[f'{k}_specks']} {k}_regions_median={g(spatial[f'{k}_regions_median'])}"
                                   for k in REGION_FITS))
        line = (f"fidelity: {head} fireflies={fireflies} unsampled={g(max(unsampled))} render_max={g(render_max)} "
                f"{spatial_line} {extra}")
        if args.docs:
            write_docs(rows, line, size, time.perf_counter() - t_start, figures)
        print(line, flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
