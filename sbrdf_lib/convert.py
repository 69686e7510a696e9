"""Conversion of any model's per-texel BRDF to the GGX microfacet model that interchange formats share.

glTF's metallic-roughness PBR, MaterialX standard_surface / OpenPBR, USD
preview surfaces and Mitsuba's ``principled`` all carry one GGX lobe plus a
diffuse term, not a Lafortune sum or a Ward lobe.  An exporter therefore does
not copy parameters: it *refits* each texel's BRDF to GGX and reports how
much was lost, per texel, on directions the fit did not see.

Method (vectorised over texels, in batches of :data:`BATCH`):

1. **Directions.**  A fixed, deterministic set of direction pairs in the
   surface frame (:func:`direction_pairs`): incident directions on a Fibonacci
   spiral over the hemisphere up to 85° from the normal, cosine-weighted
   (sin²θ uniform), each paired with (a) outgoing directions mirrored about
   half-vectors on a second Fibonacci spiral concentrated near the normal
   (θ_h up to 60°, density ∝ 1/θ_h: the specular lobe) and (b) outgoing
   directions on a cosine-weighted Fibonacci spiral (the diffuse part).  Pairs
   below 85° are kept.  The *held-out* set uses different spiral counts and a
   rotated azimuth, so no held-out pair is a fitting pair.
2. **Fit.**  The source model is evaluated on the fitting pairs and the
   installed ``cook-torrance`` model with ``distribution: ggx`` (ρ_d, F0, α;
   the caller passes it, from ``registry.create("brdf-model", "cook-torrance",
   {"distribution": "ggx"})``) is fitted with the shared batched LM
   (:func:`sbrdf_lib.lm.fit_model`) from the best of five roughness values
   (:data:`START_ALPHAS`, ρ_d and F0 solved linearly for each), on f_r itself, unweighted, as
   every fitter of the project fits (the 85° limit keeps grazing f_r bounded).
   A source that already is cook-torrance GGX skips the fit (its parameters,
   clipped to the declared bounds, are the fit).
3. **glTF** (:func:`to_gltf_pbr`).  glTF 2.0 Appendix B's BRDF with
   ``KHR_materials_specular`` (ratified form)::

       f = (1 − m) [(1 − s·max(F)) c/π + s F D V] + m D V (c + (1 − c)(1 − v·h)⁵)
       F = F0 + (1 − F0)(1 − v·h)⁵,   F0 = min(0.04 · specularColor, 1),   α = roughness²

   with D and V (height-correlated Smith) exactly the cook-torrance GGX
   terms.  Each texel gets one of two readings of its GGX fit, whichever
   reproduces the source better on the fitting pairs: *dielectric*
   (metallic 0, s = specularFactor = 1, specularColor = F0/0.04, base colour
   solved linearly against the source with the (1 − max F) diffuse weight) or
   *metal* (metallic 1, base colour = F0, no diffuse); metal wins ties (within
   :data:`METAL_PREFERENCE`), since core glTF readers without the extension
   show it right.  roughness = √α
   clipped to [0, 1].
4. **Error.**  Per texel, the relative RMS of the converted BRDF against the
   source on the held-out pairs, weighted by cos θ_i cos θ_o:
   ``sqrt(Σ w |f_conv − f_src|²) / sqrt(Σ w |f_src|²)`` over RGB.  A texel
   whose source is zero on every fitting pair gets ρ_d = F0 = 0 (GGX cannot
   be black: Schlick's F → 1 at grazing, so :func:`to_ggx` reports error 1
   there) and in glTF base colour 0, specularFactor 0: exactly black, error 0; a texel with non-finite source parameters or values is
   *invalid*: its outputs are the defaults (black, roughness 1) and its error
   is 1 (everything lost), so maps stay finite.

5. **Anisotropy** (glTF only, when the caller passes the installed
   ``ggx-anisotropic`` model, :func:`anisotropic_model`).  The source is also
   refitted to the anisotropic GGX lobe of ``KHR_materials_anisotropy``
   (α_t, α_b and a per-texel direction φ; starting points: the roughness
   grid × aspect ratios 1, 3, 1/3 × φ ∈ {0, ±π/4} and, for a Lafortune source
   with ``beta``, ±β).  Its canonical form (α_t ≥ α_b) reads as roughness =
   √α_b, anisotropy strength = √((α_t − α_b)/(1 − α_b)) and direction
   (cos φ, sin φ) in the tangent frame.  A texel keeps the anisotropic reading
   only where it lowers the error on the fitting pairs by more than
   :data:`ANISOTROPY_GAIN`, so an isotropic source converts exactly as without it.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "ANISOTROPY_GAIN",
    "BATCH",
    "DIELECTRIC_F0",
    "GLTF_MAPS",
    "MAX_THETA_DEG",
    "START_ALPHAS",
    "METAL_PREFERENCE",
    "anisotropic_model",
    "direction_pairs",
    "ggx_model",
    "gltf_brdf",
    "relative_error",
    "to_ggx",
    "to_ggx_blocks",
    "to_gltf_pbr",
    "to_gltf_pbr_blocks",
]

#: Texels converted per batch (bounds memory: the LM's Jacobian is T × S × 3 × 7 doubles).
BATCH = 512
#: Largest angle from the normal of any fitting or held-out direction.
MAX_THETA_DEG = 85.0
#: A texel reads as metal (metallic 1) when that costs at most this much more relative error than the dielectric reading.
METAL_PREFERENCE = 0.01
#: F0 of glTF's default dielectric (IOR 1.5).
DIELECTRIC_F0 = 0.04
#: The per-texel maps :func:`to_gltf_pbr` returns and their channels (linear values; ``specular_color`` may exceed 1).
GLTF_MAPS = {"base_color": 3, "metallic": 1, "roughness": 1, "specular": 1, "specular_color": 3, "anisotropy": 3}
#: ``anisotropy`` map of an isotropic texel: direction (1, 0) (the tangent), strength 0.
ISOTROPIC = (1.0, 0.0, 0.0)
#: A texel reads as anisotropic when that lowers its relative error on the fitting pairs by more than this.
ANISOTROPY_GAIN = 0.005
_GOLDEN = np.pi * (3.0 - np.sqrt(5.0))


def _fibonacci(n: int, max_theta: float, cosine: bool, phase: float) -> np.ndarray:
    """``n`` Fibonacci-spiral unit vectors up to ``max_theta`` (rad): cosine-weighted (sin²θ uniform) or uniform in solid angle."""
    u = (np.arange(n) + 0.5) / n
    if cosine:
        sin_t = np.sqrt(u) * np.sin(max_theta)
        cos_t = np.sqrt(1.0 - sin_t**2)
    else:
        cos_t = 1.0 - u * (1.0 - np.cos(max_theta))
        sin_t = np.sqrt(1.0 - cos_t**2)
    phi = phase + _GOLDEN * np.arange(n)
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)


def direction_pairs(held_out: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The fixed ``(wi, wo)`` pairs, ``(S, 3)`` each (module docstring, step 1).

    Fitting: 16 incident × (16 mirrored + 8 cosine-weighted) outgoing; held-out:
    13 × (11 + 6), azimuths rotated, so the two sets share no pair.
    """
    n_i, n_h, n_d = (13, 11, 6) if held_out else (16, 16, 8)
    phase = 1.0 if held_out else 0.0
    limit = np.radians(MAX_THETA_DEG)
    wi = _fibonacci(n_i, limit, True, phase)
    # half-vectors: θ_h = 60° · u², dense near the normal where sharp lobes live
    u = (np.arange(n_h) + 0.5) / n_h
    th = np.radians(60.0) * u**2
    ph = phase + 0.7 + _GOLDEN * np.arange(n_h)
    h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    d = np.einsum("ik,hk->ih", wi, h)
    wo_mirror = 2.0 * d[..., None] * h[None] - wi[:, None]
    wo_diffuse = np.broadcast_to(_fibonacci(n_d, limit, True, phase + 2.1)[None], (n_i, n_d, 3))
    wo = np.concatenate([wo_mirror, wo_diffuse], axis=1)
    wi_all = np.broadcast_to(wi[:, None], wo.shape)
    wo, wi_all = wo.reshape(-1, 3), wi_all.reshape(-1, 3)
    keep = wo[:, 2] >= np.cos(limit)
    wo = wo[keep] / np.linalg.norm(wo[keep], axis=1, keepdims=True)
    return np.ascontiguousarray(wi_all[keep]), np.ascontiguousarray(wo)


def ggx_model(registry=None):
    """The installed ``cook-torrance`` model with GGX facets, the conversion target.

    ``registry`` is the run's (an exporter's ``bind``); without one, the
    installed plugins' (an exporter used directly, outside a graph).
    """
    if registry is None:
        from sbrdf_core.registry import default_registry

        registry = default_registry()
    return registry.create("brdf-model", "cook-torrance", {"distribution": "ggx"})


def anisotropic_model(registry=None):
    """The installed ``ggx-anisotropic`` model (``KHR_materials_anisotropy``'s lobe), the anisotropic target."""
    if registry is None:
        from sbrdf_core.registry import default_registry

        registry = default_registry()
    return registry.create("brdf-model", "ggx-anisotropic", {})


def _eval(model, params: dict, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    T = next(iter(params.values())).shape[0]
    with np.errstate(all="ignore"):
        return model.eval(params, np.broadcast_to(wi, (T,) + wi.shape), np.broadcast_to(wo, (T,) + wo.shape))


def _cos_weight(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    return wi[:, 2] * wo[:, 2]


def relative_error(f: np.ndarray, f_src: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Per-texel cosine-weighted relative RMS ``sqrt(Σ w|f − f_src|²) / sqrt(Σ w|f_src|²)``, ``(T,)``.

    ``f``, ``f_src``: ``(T, S, 3)``; ``wi``, ``wo``: the shared ``(S, 3)`` pairs.
    Zero source: 0 where ``f`` is zero too, else 1; non-finite values give 1.
    """
    w = _cos_weight(wi, wo)[None, :, None]
    with np.errstate(all="ignore"):
        num = np.sqrt(np.sum(w * (f - f_src) ** 2, axis=(1, 2)))
        den = np.sqrt(np.sum(w * f_src**2, axis=(1, 2)))
        err = num / den
    tiny = den <= 1e-12
    err = np.where(tiny, np.where(num <= 1e-12, 0.0, 1.0), err)
    return np.where(np.isfinite(err), err, 1.0)


def _prepare(model, params: dict, wi: np.ndarray, wo: np.ndarray):
    """Source values on the pairs and the texels whose parameters and values are finite."""
    names = [p.name for p in model.parameters]
    arrays = {n: np.asarray(params[n], np.float64) for n in names}
    T = arrays[names[0]].shape[0]
    ok = np.ones(T, bool)
    for a in arrays.values():
        ok &= np.isfinite(a).all(axis=1)
    defaults = model.defaults(T)
    clean = {n: np.where(ok[:, None], arrays[n], defaults[n]) for n in names}
    f = _eval(model, clean, wi, wo)
    ok &= np.isfinite(f).all(axis=(1, 2))
    return np.where(ok[:, None, None], np.nan_to_num(f), 0.0), ok


def to_ggx(model, params: dict, ggx, *, starts: int = 1, iterations: int = 50) -> dict[str, np.ndarray]:
    """Refit ``model`` with per-texel ``params`` (``{name: (T, C)}``) to ``ggx`` (cook-torrance, GGX).

    Returns ``{"rho_d": (T, 3), "f0": (T, 3), "alpha": (T, 1), "error": (T,), "valid": (T,) bool}``:
    the GGX parameters (``ggx``'s: ``alpha_t``, ``alpha_b``, ``phi`` for the
    ``ggx-anisotropic`` target), the held-out relative error of the GGX fit itself, and
    which texels had finite source parameters (others: GGX defaults, error 1).
    For exporters to formats that carry ρ_d, F0 and α directly (MaterialX, USD,
    Mitsuba) this is the conversion; glTF adds its own reading (:func:`to_gltf_pbr`).
    """
    from sbrdf_lib.lm import fit_model

    wi, wo = direction_pairs()
    hi_wi, hi_wo = direction_pairs(held_out=True)
    T = np.asarray(params[model.parameters[0].name]).shape[0]
    out = {**{p.name: np.zeros((T, p.channels)) for p in ggx.parameters}, "error": np.ones(T),
           "valid": np.zeros(T, bool)}
    for s in range(0, T, BATCH):
        sl = slice(s, min(s + BATCH, T))
        sub = {p.name: np.asarray(params[p.name], np.float64)[sl] for p in model.parameters}
        res = _to_ggx_batch(model, sub, ggx, wi, wo, hi_wi, hi_wo, starts, iterations, fit_model)
        for k, v in res.items():
            out[k][sl] = v
    return out


def _to_ggx_batch(model, params, ggx, wi, wo, hi_wi, hi_wo, starts, iterations, fit_model):
    f_src, ok = _prepare(model, params, wi, wo)
    T, S = f_src.shape[:2]
    if _same_model(model, ggx):  # already GGX: the parameters are the fit (clipped to the declared bounds)
        fitted = {p.name: np.clip(params[p.name], *p.bounds) for p in ggx.parameters}
    else:
        valid = np.broadcast_to(ok[:, None], (T, S)).copy()
        bwi, bwo = np.broadcast_to(wi, (T, S, 3)), np.broadcast_to(wo, (T, S, 3))
        initial = ggx.fit_form().from_model(_initial_guess(ggx, f_src, valid, bwi, bwo, params))
        fitted, _, _ = fit_model(ggx, f_src, valid, bwi, bwo, initial=initial, starts=starts, iterations=iterations)
    defaults = ggx.defaults(T)
    black = ok & (np.abs(f_src).max(axis=(1, 2)) == 0.0)  # a black texel converts to exactly black
    res = {k: np.where(ok[:, None], np.nan_to_num(np.asarray(fitted[k], np.float64)), defaults[k])
           for k in (p.name for p in ggx.parameters)}
    res["rho_d"] = np.where(black[:, None], 0.0, res["rho_d"])
    res["f0"] = np.where(black[:, None], 0.0, res["f0"])
    hi_src, hi_ok = _prepare(model, params, hi_wi, hi_wo)
    err = relative_error(_eval(ggx, res, hi_wi, hi_wo), hi_src, hi_wi, hi_wo)
    ok &= hi_ok
    res["error"] = np.where(ok, err, 1.0)
    res["valid"] = ok
    return res


#: Roughness values α the starting point is chosen among (per texel, magnitudes solved linearly for each).
START_ALPHAS = (0.03, 0.08, 0.2, 0.45, 1.0)


def _shapes(ggx, T: int, source: dict):
    """The starting shapes: :data:`START_ALPHAS` (× aspect ratios and directions for the anisotropic target)."""
    if "alpha" in {p.name for p in ggx.parameters}:
        for a in START_ALPHAS:
            yield {"alpha": np.full((T, 1), a)}
        return
    phis = [np.zeros((T, 1)), np.full((T, 1), np.pi / 4), np.full((T, 1), -np.pi / 4)]
    if "beta" in source:  # Lafortune's anisotropy angle: its axes, either sign convention
        beta = np.nan_to_num(np.asarray(source["beta"], np.float64)[:, :1])
        phis += [beta, -beta]
    for a in START_ALPHAS:
        yield {"alpha_t": np.full((T, 1), a), "alpha_b": np.full((T, 1), a), "phi": phis[0]}
        for ratio in (3.0, 1.0 / 3.0):
            for phi in phis:
                yield {"alpha_t": np.full((T, 1), min(a * np.sqrt(ratio), 1.0)),
                       "alpha_b": np.full((T, 1), min(a / np.sqrt(ratio), 1.0)), "phi": phi}


def _initial_guess(ggx, f_src, valid, wi, wo, source=None) -> dict[str, np.ndarray]:
    """Per texel, the best of the starting shapes (:func:`_shapes`) with ρ_d and F0 solved linearly for each."""
    T = f_src.shape[0]
    best, best_cost = None, np.full(T, np.inf)
    for shape in _shapes(ggx, T, source or {}):
        guess = ggx.refine_linear({**ggx.defaults(T), **shape}, f_src, valid, wi, wo)
        with np.errstate(all="ignore"):
            cost = np.sum(valid[..., None] * (ggx.eval(guess, wi, wo) - f_src) ** 2, axis=(1, 2))
        cost = np.where(np.isfinite(cost), cost, np.inf)
        if best is None:
            best, best_cost = guess, cost
            continue
        better = cost < best_cost
        best = {k: np.where(better[:, None], guess[k], best[k]) for k in best}
        best_cost = np.where(better, cost, best_cost)
    return best


def _same_model(model, ggx) -> bool:
    return (model.name == ggx.name and getattr(model, "distribution", None) == getattr(ggx, "distribution", "")
            and [p.name for p in model.parameters] == [p.name for p in ggx.parameters])


def gltf_brdf(ggx, gltf: dict, wi: np.ndarray, wo: np.ndarray, anisotropic=None) -> np.ndarray:
    """glTF 2.0's metallic-roughness BRDF (Appendix B) with ``KHR_materials_specular``, ``(T, S, 3)``.

    ``gltf``: the :data:`GLTF_MAPS` per texel (linear; ``specular_color`` is the
    factor × texture product, ``specular`` the specularFactor).  ``wi``, ``wo``:
    shared ``(S, 3)`` pairs.  D·V comes from ``ggx`` (cook-torrance GGX with F0 = 1, ρ_d = 0),
    or, where ``anisotropic`` (the ``ggx-anisotropic`` model) is given and some texel's
    ``anisotropy`` strength is not 0, from it with ``KHR_materials_anisotropy``'s
    α_b = roughness², α_t = mix(roughness², 1, strength²) and the map's direction.
    """
    bc = np.asarray(gltf["base_color"], np.float64)
    m = np.asarray(gltf["metallic"], np.float64)[:, None, :1]
    rough = np.clip(np.asarray(gltf["roughness"], np.float64)[:, :1], 0.0, 1.0)
    s = np.asarray(gltf["specular"], np.float64)[:, None, :1]
    spec_col = np.asarray(gltf["specular_color"], np.float64)
    T = bc.shape[0]
    alpha = np.maximum(rough**2, 1e-3)
    aniso = np.asarray(gltf.get("anisotropy", np.broadcast_to(ISOTROPIC, (T, 3))), np.float64)
    lobe = {"rho_d": np.zeros((T, 3)), "f0": np.ones((T, 3))}
    if anisotropic is not None and (aniso[:, 2] > 0).any():
        strength = np.clip(aniso[:, 2:3], 0.0, 1.0)
        lobe.update(alpha_b=alpha, alpha_t=np.maximum(rough**2 + (1.0 - rough**2) * strength**2, 1e-3),
                    phi=np.arctan2(aniso[:, 1:2], aniso[:, 0:1]))
        dv = _eval(anisotropic, lobe, wi, wo)[..., :1]
    else:
        dv = _eval(ggx, {**lobe, "alpha": alpha}, wi, wo)[..., :1]  # (T, S, 1)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
    s5 = ((1.0 - np.clip(np.einsum("sk,sk->s", wi, h), 0.0, 1.0)) ** 5)[None, :, None]
    f0 = np.minimum(DIELECTRIC_F0 * spec_col, 1.0)[:, None, :]
    fr = f0 + (1.0 - f0) * s5
    dielectric = (1.0 - s * fr.max(axis=-1, keepdims=True)) * bc[:, None, :] / np.pi + s * fr * dv
    metal = dv * (bc[:, None, :] + (1.0 - bc[:, None, :]) * s5)
    up = ((wi[:, 2] > 0) & (wo[:, 2] > 0))[None, :, None]
    return np.where(up, (1.0 - m) * dielectric + m * metal, 0.0)


def to_gltf_pbr(model, params: dict, ggx, *, starts: int = 1, iterations: int = 50, anisotropic=None):
    """Refit to GGX and read the fit as glTF metallic-roughness (+ KHR_materials_specular) per texel.

    ``params``: ``{name: (T, C)}`` of ``model``; ``ggx``: :func:`ggx_model`;
    ``anisotropic``: :func:`anisotropic_model` to also try ``KHR_materials_anisotropy``
    (only for a model that may be anisotropic: its ``anisotropic`` is not False).
    Returns ``(gltf, error)``: ``gltf`` holds the :data:`GLTF_MAPS` as ``(T, C)``
    linear values (``specular_color`` = F0/0.04, may exceed 1: the writer folds
    it into ``specularColorFactor`` × texture; ``anisotropy`` = direction x, y and
    strength), ``error`` ``(T,)`` the held-out
    cosine-weighted relative RMS of glTF's BRDF against the source (1 for invalid texels).
    """
    fits = [(to_ggx(model, params, ggx, starts=starts, iterations=iterations), None)]
    if anisotropic is not None and getattr(model, "anisotropic", True):
        fits.append((to_ggx(model, params, anisotropic, starts=starts, iterations=iterations), anisotropic))
    T = fits[0][0]["error"].shape[0]
    gltf = {k: np.zeros((T, c)) for k, c in GLTF_MAPS.items()}
    error = np.ones(T)
    wi, wo = direction_pairs()
    hi_wi, hi_wo = direction_pairs(held_out=True)
    for s in range(0, T, BATCH):
        sl = slice(s, min(s + BATCH, T))
        sub = {p.name: np.asarray(params[p.name], np.float64)[sl] for p in model.parameters}
        g, e = _gltf_batch(model, sub, ggx, [({k: v[sl] for k, v in f.items()}, a) for f, a in fits],
                           wi, wo, hi_wi, hi_wo)
        for k in GLTF_MAPS:
            gltf[k][sl] = g[k]
        error[sl] = e
    return gltf, error


def _readings(ggx, fit, anisotropic, f_src, wi, wo) -> tuple[dict, np.ndarray]:
    """The better of a GGX fit's two glTF readings per texel, dielectric or metal, and its error on ``wi, wo``."""
    T = fit["f0"].shape[0]
    f0 = fit["f0"]
    if anisotropic is None:
        rough, aniso = np.clip(np.sqrt(np.maximum(fit["alpha"], 0.0)), 0.0, 1.0), np.broadcast_to(ISOTROPIC, (T, 3))
    else:  # KHR_materials_anisotropy: α_b = roughness², α_t = mix(α_b, 1, strength²), direction (cos φ, sin φ)
        c = anisotropic.canonical(fit)
        ab, at = np.clip(c["alpha_b"], 0.0, 1.0), np.clip(c["alpha_t"], 0.0, 1.0)
        rough = np.sqrt(ab)
        with np.errstate(all="ignore"):
            strength = np.sqrt(np.clip(np.nan_to_num((at - ab) / (1.0 - ab)), 0.0, 1.0))
        aniso = np.concatenate([np.cos(c["phi"]), np.sin(c["phi"]), strength], axis=1)
    ones, zeros = np.ones((T, 1)), np.zeros((T, 1))
    # dielectric reading: F0 in specularColor, base colour solved linearly (f is affine in it)
    spec_col = np.clip(f0 / DIELECTRIC_F0, 0.0, 1.0 / DIELECTRIC_F0)
    diel = {"base_color": np.zeros((T, 3)), "metallic": zeros, "roughness": rough, "specular": ones,
            "specular_color": spec_col, "anisotropy": aniso}
    offset = gltf_brdf(ggx, diel, wi, wo, anisotropic)
    basis = gltf_brdf(ggx, {**diel, "base_color": np.ones((T, 3))}, wi, wo, anisotropic) - offset
    w = _cos_weight(wi, wo)[None, :, None]
    with np.errstate(all="ignore"):
        bc = np.sum(w * basis * (f_src - offset), axis=1) / np.sum(w * basis * basis, axis=1)
    diel["base_color"] = np.clip(np.nan_to_num(bc), 0.0, 1.0)
    metal = {"base_color": np.clip(f0, 0.0, 1.0), "metallic": ones, "roughness": rough, "specular": ones,
             "specular_color": np.ones((T, 3)), "anisotropy": aniso}
    e_diel = relative_error(gltf_brdf(ggx, diel, wi, wo, anisotropic), f_src, wi, wo)
    e_metal = relative_error(gltf_brdf(ggx, metal, wi, wo, anisotropic), f_src, wi, wo)
    # the metal reading is what core glTF (no extension) shows right: preferred unless it costs more than 1 %
    use_metal = e_metal <= e_diel + METAL_PREFERENCE
    reading = {k: np.where(use_metal[:, None], metal[k], diel[k]) for k in GLTF_MAPS}
    return reading, np.where(use_metal, e_metal, e_diel)


def _gltf_batch(model, params, ggx, fits, wi, wo, hi_wi, hi_wo):
    T = fits[0][0]["f0"].shape[0]
    f_src, ok = _prepare(model, params, wi, wo)
    anisotropic = None
    gltf, err = None, None
    for fit, target in fits:  # the isotropic reading, then (if given) the anisotropic one where it gains enough
        ok &= fit["valid"]
        reading, e = _readings(ggx, fit, target, f_src, wi, wo)
        if gltf is None:
            gltf, err = reading, e
            continue
        anisotropic = target
        better = e < err - ANISOTROPY_GAIN
        gltf = {k: np.where(better[:, None], reading[k], gltf[k]) for k in GLTF_MAPS}
        err = np.where(better, e, err)
    assert gltf is not None
    zeros = np.zeros((T, 1))
    default = {"base_color": np.zeros((T, 3)), "metallic": zeros, "roughness": np.ones((T, 1)), "specular": np.ones((T, 1)),
               "specular_color": np.ones((T, 3)), "anisotropy": np.broadcast_to(ISOTROPIC, (T, 3))}
    gltf = {k: np.where(ok[:, None], gltf[k], default[k]) for k in GLTF_MAPS}
    black = ok & (np.abs(f_src).max(axis=(1, 2)) == 0.0)  # glTF can be exactly black: no diffuse, specularFactor 0
    gltf["base_color"] = np.where(black[:, None], 0.0, gltf["base_color"])
    gltf["metallic"] = np.where(black[:, None], 0.0, gltf["metallic"])
    gltf["specular"] = np.where(black[:, None], 0.0, gltf["specular"])
    hi_src, hi_ok = _prepare(model, params, hi_wi, hi_wo)
    err = relative_error(gltf_brdf(ggx, gltf, hi_wi, hi_wo, anisotropic), hi_src, hi_wi, hi_wo)
    return gltf, np.where(ok & hi_ok, err, 1.0)


def _blocks(fn, names_out: dict[str, int], model, params: dict, **kw) -> dict:
    """Apply a per-texel ``fn(model, {name: (T, C)}) -> {out: (T, C)}`` over aligned ``(V, U, C)`` dask blocks."""
    import dask.array as da

    names = [p.name for p in model.parameters]
    arrays = [da.asarray(params[n]).rechunk({2: -1}) for n in names]
    K = sum(names_out.values())

    def block(*blocks):
        V, U = blocks[0].shape[:2]
        flat = {n: np.asarray(b, np.float64).reshape(V * U, -1) for n, b in zip(names, blocks)}
        res = fn(model, flat, **kw)
        return np.concatenate([np.asarray(res[k], np.float32).reshape(V, U, -1) for k in names_out], axis=-1)

    arrays = da.core.unify_chunks(*[x for a in arrays for x in (a, "vuc")])[1]
    stacked = da.map_blocks(block, *arrays, dtype=np.float32, chunks=arrays[0].chunks[:2] + ((K,),))
    out, k = {}, 0
    for name, c in names_out.items():
        out[name] = stacked[..., k:k + c]
        k += c
    return out


def to_ggx_blocks(model, params: dict, ggx, **kw) -> dict:
    """Lazy :func:`to_ggx` over ``(V, U, C)`` dask maps: ``{"rho_d", "f0", "alpha", "error" (V, U, 1)}``, float32."""

    def fn(model, flat, **kw):
        r = to_ggx(model, flat, ggx, **kw)
        return {**r, "error": r["error"][:, None]}

    return _blocks(fn, {"rho_d": 3, "f0": 3, "alpha": 1, "error": 1}, model, params, **kw)


def to_gltf_pbr_blocks(model, params: dict, ggx, **kw) -> dict:
    """Lazy :func:`to_gltf_pbr` over ``(V, U, C)`` dask maps: the :data:`GLTF_MAPS` and ``error`` ``(V, U, 1)``, float32."""

    def fn(model, flat, **kw):
        g, e = to_gltf_pbr(model, flat, ggx, **kw)
        return {**g, "error": e[:, None]}

    return _blocks(fn, {**GLTF_MAPS, "error": 1}, model, params, **kw)
