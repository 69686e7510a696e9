"""Conversion of any model's per-texel BRDF to the GGX microfacet model that interchange formats share.

glTF's metallic-roughness PBR (with ``KHR_materials_specular``), MaterialX
standard_surface / OpenPBR, USD preview surfaces and Mitsuba's rough
conductor all carry one GGX lobe plus a diffuse term, not a Lafortune sum or
a Ward lobe.  An exporter therefore does not copy parameters: it *refits*
each texel's BRDF to GGX and reports how much was lost, per texel, on
directions the fit did not see.

Method (vectorised over texels, in batches of :data:`BATCH`):

1. **Directions.**  A fixed, deterministic set of direction pairs in the
   surface frame (:func:`direction_pairs`): incident directions on a Fibonacci
   spiral over the directions a viewer meets, up to :data:`VIEW_THETA_DEG`
   (70°) from the normal by default (the exporters' ``max_theta_deg``), cosine-weighted
   (sin²θ uniform), each paired with (a) outgoing directions mirrored about
   half-vectors on a second Fibonacci spiral concentrated near the normal
   (θ_h up to 60°, density ∝ 1/θ_h: the specular lobe) and (b) outgoing
   directions on a cosine-weighted Fibonacci spiral (the diffuse part).  Pairs
   within the limit are kept.  The *held-out* set uses different spiral counts and a
   rotated azimuth, so no held-out pair is a fitting pair.
2. **Target.**  The GGX lobe of the installed ``cook-torrance`` model
   (``distribution: ggx``; or ``ggx-anisotropic``), read the way glTF's
   ``KHR_materials_specular``, OpenPBR and standard_surface weigh it
   (:class:`SpecularGGX`)::

       f = ρ_d + s (F0c + (1 − F0c)(1 − ω_i·h)⁵) D V

   with a specular weight s ∈ [0, 1] (glTF's specularFactor) and a specular
   colour F0c ∈ [0, 1] (normal-incidence Fresnel before the weight), α ≤ 1
   (glTF's roughness = √α ≤ 1).  Why the weight: Schlick's term rises to 1 at
   grazing whatever F0 is, and a measured lobe that does not brighten toward
   grazing (every Lafortune or Phong fit) can only be matched with F0 → 0 and
   the lobe spread flat (α at its bound) unless the grazing rise can be dimmed
   too.  Formats whose Fresnel rises to 1 regardless (USD Preview Surface) are
   fitted with s fixed at 1 (``grazing=False``).
3. **Fit.**  Each texel starts from the best of a few shapes: the roughness
   grid :data:`START_ALPHAS` and the source's own mapped roughness (a
   Lafortune or Phong exponent n as α = √(2/(n + 2)), the Beckmann match of a
   cosine lobe; a microfacet model's α as it is), with ρ_d, s·F0c and s solved
   by linear least squares for each.  The shared batched LM
   (:func:`sbrdf_lib.lm.fit_model`) then refines it on the cosine-weighted
   objective ∫∫ |f − f_src|² cos θ_i cos θ_o dω_i dω_o, summed over the pairs
   with the quadrature weights of :func:`pair_weight` (:class:`CosineWeighted`):
   a renderer's pixel sees f · cos θ_i under a light, and a surface seen at
   θ_o covers cos θ_o of the image it would cover face-on.  Without the
   quadrature weights the many pairs packed at each specular peak rule the
   sum, and a lobe GGX cannot follow there is traded for a brighter diffuse.  An unweighted fit
   is ruled by the grazing pairs, where GGX's 1/(cos θ_i cos θ_o) peak is
   largest and a viewer rarely looks.  A source that already is cook-torrance
   GGX skips the fit (its parameters, clipped to the target's bounds, s = 1,
   are the fit).
4. **glTF** (:func:`to_gltf_pbr`).  glTF 2.0 Appendix B's BRDF with
   ``KHR_materials_specular`` (ratified form)::

       f = (1 − m) [(1 − s·max(F)) c/π + s F D V] + m D V (c + (1 − c)(1 − v·h)⁵)
       F = F0 + (1 − F0)(1 − v·h)⁵,   F0 = min(0.04 · specularColor, 1),   α = roughness²

   Each texel gets one of two readings of its fit, whichever reproduces the
   source better on the fitting pairs: *dielectric* (metallic 0,
   specularFactor = s, specularColor = F0c/0.04, base colour solved linearly
   against the source with the (1 − s·max F) diffuse weight) or *metal*
   (metallic 1, base colour = s·F0c, no diffuse); metal wins ties (within
   :data:`METAL_PREFERENCE`), since core glTF readers without the extension
   show it right.  roughness = √α.
5. **Error.**  Per texel, the relative RMS of the converted BRDF against the
   source on the held-out pairs, each weighted by its :func:`pair_weight`
   (the cosine-weighted integral over the hemisphere):
   ``sqrt(Σ w |f_conv − f_src|²) / sqrt(Σ w |f_src|²)`` over RGB.  Texels whose
   error is above the exporter's ``flag_error`` (default :data:`FLAG_ERROR`)
   are flagged: the format cannot show them as fitted.  A texel whose source is
   zero on every fitting pair converts to exactly black (ρ_d = s = 0), error 0;
   a texel with non-finite source parameters or values is *invalid*: its
   outputs are the defaults (black, roughness 1) and its error is 1
   (everything lost), so maps stay finite.
6. **Anisotropy** (glTF only, when the caller passes the installed
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

from functools import partial

import numpy as np

from sbrdf_core.brdf import BRDFModel, LogFitForm, ModelParameter, above_horizon

__all__ = [
    "ANISOTROPY_GAIN",
    "BATCH",
    "DIELECTRIC_F0",
    "FLAG_ERROR",
    "GGX_MAPS",
    "GLTF_MAPS",
    "MAX_THETA_DEG",
    "VIEW_THETA_DEG",
    "START_ALPHAS",
    "METAL_PREFERENCE",
    "CosineWeighted",
    "SpecularGGX",
    "anisotropic_model",
    "direction_pairs",
    "ggx_model",
    "gltf_brdf",
    "mapped_alpha",
    "pair_weight",
    "ProjectedWeighted",
    "relative_error",
    "sample_error",
    "samples_to_gltf",
    "samples_to_gltf_blocks",
    "to_ggx",
    "to_ggx_blocks",
    "to_gltf_pbr",
    "to_gltf_pbr_blocks",
]

#: Texels converted per batch (bounds memory: the LM's Jacobian is T × S × 3 × 8 doubles).
BATCH = 512
#: Largest angle from the normal of any fitting or held-out direction (:func:`direction_pairs`' default).
MAX_THETA_DEG = 85.0
#: The conversion's default limit: the directions a viewer meets.  A surface seen or lit beyond 70° from its
#: normal shows at most cos 70° = 34 % of its face-on area or irradiance, and there GGX's Fresnel and
#: 1/(cos θ_i cos θ_o) rise would otherwise rule the fit of a measured lobe that does not follow them.
VIEW_THETA_DEG = 70.0
#: A texel reads as metal (metallic 1) when that costs at most this much more relative error than the dielectric reading.
METAL_PREFERENCE = 0.01
#: F0 of glTF's default dielectric (IOR 1.5).
DIELECTRIC_F0 = 0.04
#: A texel whose held-out conversion error is above this is flagged (the exporters' ``flag_error`` default).
FLAG_ERROR = 0.25
#: Largest GGX α any format carries (glTF, OpenPBR and USD: roughness = √α ≤ 1).
MAX_ALPHA = 1.0
#: The per-texel maps :func:`to_gltf_pbr` returns and their channels (linear values; ``specular_color`` may exceed 1).
GLTF_MAPS = {"base_color": 3, "metallic": 1, "roughness": 1, "specular": 1, "specular_color": 3, "anisotropy": 3}
#: The per-texel maps :func:`to_ggx_blocks` returns: ρ_d, s·F0c (the normal-incidence Fresnel), α, s, F0c, error.
GGX_MAPS = {"rho_d": 3, "f0": 3, "alpha": 1, "specular": 1, "specular_color": 3, "error": 1}
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


def direction_pairs(held_out: bool = False, max_theta_deg: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The fixed ``(wi, wo)`` pairs, ``(S, 3)`` each (module docstring, step 1).

    Fitting: 16 incident × (16 mirrored + 8 cosine-weighted) outgoing; held-out:
    13 × (11 + 6), azimuths rotated, so the two sets share no pair.
    """
    n_i, n_h, n_d = (13, 11, 6) if held_out else (16, 16, 8)
    phase = 1.0 if held_out else 0.0
    limit = np.radians(MAX_THETA_DEG if max_theta_deg is None else max_theta_deg)
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


#: Largest half-vector angle of the mirrored pairs (:func:`direction_pairs`), rad.
_MIRROR_THETA_H = np.radians(60.0)
#: The share of mirrored pairs among a fitting set's outgoing directions (16 of 24; held-out 11 of 17).
_MIRROR_SHARE = 2.0 / 3.0


def pair_weight(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Quadrature weight of each ``(wi, wo)`` pair of :func:`direction_pairs` for ∫∫ g cos θ_i cos θ_o dω_i dω_o.

    The pairs are not spread evenly: two thirds are mirrored about half-vectors
    packed near the normal (density p_m(ω_o | ω_i) = p(h) / (4 ω_o·h) with
    p(h) = 1 / (4π sin θ_h √(Θ θ_h)), θ_h = Θ u², Θ = 60°), a third are
    cosine-distributed (p_d = cos θ_o / π); the incident directions are
    cosine-distributed, which accounts for cos θ_i.  The balance heuristic's
    weight cos θ_o / (⅔ p_m + ⅓ p_d) turns a sum over the pairs into the
    cosine-weighted integral a renderer's pixels add up, instead of one ruled
    by the many pairs at each specular peak.  The scale is arbitrary (only
    ratios are used); 0 below the horizon.  Shaped like ``wi`` without its last axis.
    """
    ci, co = wi[..., 2], wo[..., 2]
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    th = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    with np.errstate(all="ignore"):
        p_h = 1.0 / (4.0 * np.pi * np.sin(th) * np.sqrt(_MIRROR_THETA_H * th))
        p_m = np.where((th > 0) & (th <= _MIRROR_THETA_H), p_h / (4.0 * np.maximum(np.sum(wo * h, axis=-1), 1e-9)), 0.0)
        p_m = np.where(th > 0, p_m, np.inf)  # the exact mirror pair: a point of the integral, weight 0
        w = co / (_MIRROR_SHARE * p_m + (1.0 - _MIRROR_SHARE) * co / np.pi)
    return np.where((ci > 0) & (co > 0) & np.isfinite(w), w, 0.0)


def ggx_model(registry=None):
    """The installed ``cook-torrance`` model with GGX facets, the conversion target's lobe.

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


def _schlick(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Schlick's weight (1 − ω_i·h)⁵, shaped like ``wi`` without its last axis."""
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    return (1.0 - np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)) ** 5


class SpecularGGX(BRDFModel):
    """The conversion target: a GGX lobe with a specular weight and colour, as glTF, OpenPBR and Standard Surface weigh it.

        f_r = ρ_d + s (F0c + (1 − F0c)(1 − ω_i·h)⁵) D V

    D V (the microfacet distribution times the height-correlated visibility)
    is the ``lobe``'s (the installed ``cook-torrance`` GGX or
    ``ggx-anisotropic``), evaluated with ρ_d = 0 and F0 = 1.  Parameters:
    ``rho_d`` (3, sr⁻¹), ``specular_color`` F0c (3, in [0, 1]), ``specular``
    s (1, in [0, 1]) and the lobe's shape (``alpha``, or ``alpha_t``,
    ``alpha_b``, ``phi``) with α ≤ :data:`MAX_ALPHA`.  Normal-incidence Fresnel
    is s·F0c, grazing s: with s = 1 it is the lobe model itself.

    >>> import numpy as np
    >>> from sbrdf_lib.convert import SpecularGGX, ggx_model
    >>> m = SpecularGGX(ggx_model())
    >>> [p.name for p in m.parameters]
    ['rho_d', 'specular_color', 'specular', 'alpha']
    >>> p = {"rho_d": np.zeros((1, 3)), "specular_color": np.full((1, 3), 0.5), "specular": np.ones((1, 1)),
    ...      "alpha": np.full((1, 1), 0.3)}
    >>> d = np.array([[[0.0, 0.0, 1.0]]])
    >>> lobe = ggx_model().eval({"rho_d": np.zeros((1, 3)), "f0": np.full((1, 3), 0.5), "alpha": p["alpha"]}, d, d)
    >>> bool(np.allclose(m.eval(p, d, d), lobe))
    True
    """

    def __init__(self, lobe: BRDFModel):
        self.lobe = lobe
        self.name = f"{lobe.name}-specular"
        self.anisotropic = getattr(lobe, "anisotropic", True)
        by_name = {p.name: p for p in lobe.parameters}
        self.shape = tuple(
            ModelParameter(p.name, p.channels, (p.bounds[0], min(p.bounds[1], MAX_ALPHA)), p.typical, p.default, p.scope,
                           unit=p.unit, doc=p.doc) if p.name.startswith("alpha") else p
            for p in lobe.parameters if p.name not in ("rho_d", "f0"))
        self.parameters = (
            by_name["rho_d"],
            ModelParameter("specular_color", 3, (0.0, 1.0), (0.02, 1.0), 0.04, unit="1", magnitude=True,
                           doc="Fresnel reflectance at normal incidence before the specular weight (F0c)"),
            ModelParameter("specular", 1, (0.0, 1.0), (0.05, 1.0), 1.0, unit="1",
                           doc="specular weight s: the lobe's Fresnel runs from s F0c (normal) to s (grazing)"),
            *self.shape,
        )

    def _lobe(self, params, T: int) -> dict:
        return {"rho_d": np.zeros((T, 3)), "f0": np.ones((T, 3)), **{p.name: params[p.name] for p in self.shape}}

    def _fresnel(self, params, wi, wo):
        S = _schlick(wi, wo)[..., None]
        c = np.asarray(params["specular_color"])[:, None, :]
        s = np.asarray(params["specular"])[:, None, :1]
        return S, c, s, s * (c + (1.0 - c) * S)

    def eval(self, params, wi, wo):
        T = wi.shape[0]
        dv = self.lobe.eval(self._lobe(params, T), wi, wo)[..., :1]  # F = 1: D V alone
        _, _, _, F = self._fresnel(params, wi, wo)
        f = np.asarray(params["rho_d"])[:, None, :] + F * dv
        return np.where(above_horizon(wi, wo)[..., None], f, 0.0)

    def jacobian(self, params, wi, wo):
        T = wi.shape[0]
        lp = self._lobe(params, T)
        dv = self.lobe.eval(lp, wi, wo)[..., 0]
        J = self.lobe.jacobian(lp, wi, wo)  # (T, S, 3, 6 + K): ρ_d, F0, then the shape columns (F = 1)
        S, c, s, F = self._fresnel(params, wi, wo)
        up = above_horizon(wi, wo).astype(float)[..., None]
        eye = np.eye(3)
        cols = [up * eye[k] for k in range(3)]
        cols += [s * (1.0 - S) * dv[..., None] * eye[k] for k in range(3)]
        cols += [(c + (1.0 - c) * S) * dv[..., None]]
        cols += [F * J[..., :1, 6 + k] for k in range(J.shape[-1] - 6)]
        return np.stack(cols, axis=-1)

    def fit_form(self) -> BRDFModel:
        """Roughness fitted as log α, like the lobe's own fit form."""
        return LogFitForm(self, getattr(self.lobe.fit_form(), "log_names", ()))

    def canonical(self, params):
        """The lobe's canonical shape (``ggx-anisotropic``: α_t ≥ α_b, φ in [−π/2, π/2))."""
        out = {k: np.asarray(v, np.float64) for k, v in params.items()}
        T = np.asarray(params["rho_d"]).shape[0]
        c = self.lobe.canonical({**self._lobe(out, T)})
        out.update({p.name: c[p.name] for p in self.shape})
        return out

    def from_lobe(self, params) -> dict:
        """The lobe model's ``rho_d``, ``f0`` and shape as this model's (s = 1, F0c = F0)."""
        out = {"rho_d": params["rho_d"], "specular_color": params["f0"],
               "specular": np.ones((np.asarray(params["f0"]).shape[0], 1))}
        out.update({p.name: np.clip(params[p.name], *p.bounds) for p in self.shape})
        return out


class CosineWeighted(BRDFModel):
    """A fit form whose f_r and Jacobian are scaled by √w, w the pair's :func:`pair_weight`.

    An unweighted least squares of this against ``√w f_src`` is the
    cosine-weighted least squares of ``form`` against ``f_src`` over the
    hemisphere (the pairs' uneven spread undone by ``w``): the engine
    (:func:`sbrdf_lib.lm.fit_model`) stays unweighted and model-agnostic.  The
    weight is a function of the directions alone, so any subset of texels the
    engine refits sees the same objective.
    """

    def __init__(self, form: BRDFModel):
        self.form = form
        self.name = f"{form.name}-cosine-weighted"
        self.parameters = form.parameters
        self.anisotropic = getattr(form, "anisotropic", True)

    @staticmethod
    def weight(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """√ of :func:`pair_weight`; shaped like ``wi`` without its last axis."""
        return np.sqrt(pair_weight(wi, wo))

    def eval(self, params, wi, wo):
        return self.form.eval(params, wi, wo) * self.weight(wi, wo)[..., None]

    def jacobian(self, params, wi, wo):
        return self.form.jacobian(params, wi, wo) * self.weight(wi, wo)[..., None, None]

    def to_model(self, params):
        return self.form.to_model(params)

    def from_model(self, params):
        return self.form.from_model(params)

    def canonical(self, params):
        return self.form.canonical(params)

    def constrain(self, params, limits):
        return self.form.constrain(params, limits)

    def fit_form(self):
        return self


class ProjectedWeighted(CosineWeighted):
    """:class:`CosineWeighted` with the weight cos θ_i cos θ_o alone: for measured samples, which come at
    the capture's directions, not as a quadrature of the hemisphere.

    Weighted so, a least-squares fit to samples counts each as a renderer's pixel sees it (lit at θ_i,
    seen at θ_o), as the conversion does on its pairs.
    """

    @staticmethod
    def weight(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """√(cos θ_i cos θ_o), 0 below the horizon; shaped like ``wi`` without its last axis."""
        return np.sqrt(np.clip(wi[..., 2], 0.0, 1.0) * np.clip(wo[..., 2], 0.0, 1.0))


def _eval(model, params: dict, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``model.eval`` on pairs shared by every texel, ``(S, 3)``, or each texel's own, ``(T, S, 3)``."""
    T = next(iter(params.values())).shape[0]
    if wi.ndim == 2:
        wi, wo = np.broadcast_to(wi, (T,) + wi.shape), np.broadcast_to(wo, (T,) + wo.shape)
    with np.errstate(all="ignore"):
        return model.eval(params, wi, wo)


def _cos_weight(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    return pair_weight(wi, wo)


def relative_error(f: np.ndarray, f_src: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Per-texel cosine-weighted relative RMS ``sqrt(Σ w|f − f_src|²) / sqrt(Σ w|f_src|²)``, ``(T,)``.

    ``f``, ``f_src``: ``(T, S, 3)``; ``wi``, ``wo``: the shared ``(S, 3)`` pairs of
    :func:`direction_pairs`, ``w`` their :func:`pair_weight` (the integral over
    the hemisphere, cos θ_i cos θ_o weighted).
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


def mapped_alpha(source: dict) -> np.ndarray | None:
    """The GGX α a source's own parameters suggest, ``(T, 1)``, or None when it has no roughness-like parameter.

    A cosine lobe cos^n (Lafortune's first lobe, Phong) falls off as
    exp(−n θ²/2) about its peak, a Beckmann/GGX lobe as exp(−θ²/(4α²)) in the
    angle of the reflected direction: α = √(2/(n + 2)) (Walter et al. 2007's
    Phong–Beckmann match).  A microfacet source's α (or the geometric mean of
    α_x, α_y) is taken as it is.
    """
    for key in ("exponent_1", "exponent"):
        if key in source:
            n = np.nan_to_num(np.asarray(source[key], np.float64)[:, :1], nan=1.0)
            return np.clip(np.sqrt(2.0 / (np.maximum(n, 0.0) + 2.0)), 1e-3, MAX_ALPHA)
    if "alpha" in source:
        return np.clip(np.nan_to_num(np.asarray(source["alpha"], np.float64)[:, :1], nan=0.2), 1e-3, MAX_ALPHA)
    ax = [k for k in source if k.startswith("alpha_")]
    if len(ax) == 2:
        a = np.sqrt(np.abs(np.asarray(source[ax[0]], np.float64)[:, :1] * np.asarray(source[ax[1]], np.float64)[:, :1]))
        return np.clip(np.nan_to_num(a, nan=0.2), 1e-3, MAX_ALPHA)
    return None


def to_ggx(model, params: dict, ggx, *, starts: int = 1, iterations: int = 8, grazing: bool = True,
           flag_error: float = FLAG_ERROR, max_theta_deg: float = VIEW_THETA_DEG) -> dict[str, np.ndarray]:
    """Refit ``model`` with per-texel ``params`` (``{name: (T, C)}``) to ``ggx``'s lobe with a specular weight.

    ``ggx``: :func:`ggx_model` or :func:`anisotropic_model`; ``grazing`` False
    fixes the specular weight s at 1 (formats whose Fresnel always rises to 1
    at grazing: USD Preview Surface).  Returns ``{"rho_d": (T, 3), "f0": (T, 3)
    (= s·F0c, the normal-incidence Fresnel), "specular": (T, 1) s,
    "specular_color": (T, 3) F0c, "alpha": (T, 1)`` (or ``alpha_t``,
    ``alpha_b``, ``phi``), ``"error": (T,)`` the held-out relative error of the
    fit itself, ``"flagged": (T,)`` error above ``flag_error``, ``"valid": (T,)``
    bool}``: which texels had finite source parameters (others: defaults, error 1).

    >>> import numpy as np
    >>> from sbrdf_lib.convert import ggx_model, to_ggx
    >>> ct = ggx_model()
    >>> p = {"rho_d": np.full((2, 3), 0.1), "f0": np.full((2, 3), 0.04), "alpha": np.array([[0.1], [0.5]])}
    >>> r = to_ggx(ct, p, ct)
    >>> r["alpha"].shape, r["error"].shape, bool(r["error"].max() < 1e-9)
    ((2, 1), (2,), True)
    """
    from sbrdf_lib.lm import fit_model

    target = SpecularGGX(ggx)
    wi, wo = direction_pairs(max_theta_deg=max_theta_deg)
    hi_wi, hi_wo = direction_pairs(held_out=True, max_theta_deg=max_theta_deg)
    T = np.asarray(params[model.parameters[0].name]).shape[0]
    out = {**{p.name: np.zeros((T, p.channels)) for p in target.parameters}, "f0": np.zeros((T, 3)),
           "error": np.ones(T), "valid": np.zeros(T, bool)}
    for s in range(0, T, BATCH):
        sl = slice(s, min(s + BATCH, T))
        sub = {p.name: np.asarray(params[p.name], np.float64)[sl] for p in model.parameters}
        res = _to_ggx_batch(model, sub, target, wi, wo, hi_wi, hi_wo, starts, iterations, grazing, fit_model)
        for k, v in res.items():
            out[k][sl] = v
    out["flagged"] = out["error"] > flag_error
    return out


def _to_ggx_batch(model, params, target, wi, wo, hi_wi, hi_wo, starts, iterations, grazing, fit_model):
    f_src, ok = _prepare(model, params, wi, wo)
    T, S = f_src.shape[:2]
    if _same_model(model, target.lobe):  # already the lobe: its parameters are the fit (clipped to the bounds)
        fitted = target.from_lobe(params)
    else:
        valid = np.broadcast_to(ok[:, None], (T, S)).copy()
        bwi, bwo = np.broadcast_to(wi, (T, S, 3)), np.broadcast_to(wo, (T, S, 3))
        fitted = start = _initial_guess(target, f_src, valid, bwi, bwo, params, grazing)
        if iterations > 0:  # 0: the linear start alone (variable projection on the α grid)
            form = target.fit_form()
            sw = CosineWeighted.weight(bwi, bwo)[..., None]
            fitted, _, _ = fit_model(CosineWeighted(form), f_src * sw, valid, bwi, bwo, initial=form.from_model(start),
                                     starts=starts, iterations=iterations, fixed=() if grazing else ("specular",))
        if not grazing:
            fitted = {**fitted, "specular": np.ones((T, 1))}
    defaults = target.defaults(T)
    black = ok & (np.abs(f_src).max(axis=(1, 2)) == 0.0)  # a black texel converts to exactly black
    res = {k: np.where(ok[:, None], np.nan_to_num(np.asarray(fitted[k], np.float64)), defaults[k])
           for k in (p.name for p in target.parameters)}
    res = {k: np.clip(v, *p.bounds) for (k, v), p in zip(res.items(), target.parameters)}
    res["rho_d"] = np.where(black[:, None], 0.0, res["rho_d"])
    res["specular"] = np.where(black[:, None], 0.0 if grazing else 1.0, res["specular"])
    res["specular_color"] = np.where(black[:, None], 0.0, res["specular_color"])
    hi_src, hi_ok = _prepare(model, params, hi_wi, hi_wo)
    err = relative_error(_eval(target, res, hi_wi, hi_wo), hi_src, hi_wi, hi_wo)
    ok &= hi_ok
    res["f0"] = res["specular"] * res["specular_color"]
    res["error"] = np.where(ok, err, 1.0)
    res["valid"] = ok
    return res


#: Roughness values α the starting point is chosen among (per texel, magnitudes solved linearly for each).
START_ALPHAS = (0.03, 0.08, 0.2, 0.45, 1.0)


def _shapes(target: SpecularGGX, T: int, source: dict):
    """The starting shapes: :data:`START_ALPHAS` and the source's :func:`mapped_alpha` (× aspect ratios and
    directions for the anisotropic target)."""
    mapped = mapped_alpha(source)
    alphas = [np.full((T, 1), a) for a in START_ALPHAS] + ([mapped] if mapped is not None else [])
    if "alpha" in {p.name for p in target.shape}:
        for a in alphas:
            yield {"alpha": a}
        return
    phis = [np.zeros((T, 1)), np.full((T, 1), np.pi / 4), np.full((T, 1), -np.pi / 4)]
    if "beta" in source:  # Lafortune's anisotropy angle: its axes, either sign convention
        beta = np.nan_to_num(np.asarray(source["beta"], np.float64)[:, :1])
        phis += [beta, -beta]
    for a in alphas:
        yield {"alpha_t": a, "alpha_b": a, "phi": phis[0]}
        for ratio in (3.0, 1.0 / 3.0):
            for phi in phis:
                yield {"alpha_t": np.minimum(a * np.sqrt(ratio), MAX_ALPHA),
                       "alpha_b": np.minimum(a / np.sqrt(ratio), MAX_ALPHA), "phi": phi}


def _solve_magnitudes(target: SpecularGGX, shape: dict, f_src, valid, wi, wo, grazing: bool, weight=CosineWeighted) -> dict:
    """ρ_d, F0c and s for a fixed lobe shape: the cosine-weighted linear least squares in (ρ_d, s·F0c, s).

    f is affine in a = s·F0c (per channel) and s given the shape: f = ρ_d + (a (1 − S) + s S) D V.  Two
    candidates, each projected onto the target's box and scored exactly: the free solution (s raised to
    max a where it fell below: F0c ≤ 1), and the flat-Fresnel one (F = a, s = max a), which is where the
    box's edge lies for a source that does not brighten toward grazing.  With ``grazing`` False, s = 1.
    ``weight``: the fit form whose ``weight(wi, wo)`` is √ of each pair's (:class:`CosineWeighted`, or
    :class:`ProjectedWeighted` for measured samples).
    """
    T = f_src.shape[0]
    dv = target.lobe.eval(target._lobe(shape, T), wi, wo)[..., 0]
    S = _schlick(wi, wo)
    up = above_horizon(wi, wo).astype(float)
    w = weight.weight(wi, wo) ** 2 * valid
    rho_bounds = target.parameters[0].bounds

    def solve(basis, rhs):
        n = basis.shape[-1]
        A = np.einsum("ts,tsci,tscj->tij", w, basis, basis)
        A += (1e-9 * np.trace(A, axis1=1, axis2=2)[:, None, None] + 1e-30) * np.eye(n)
        b = np.einsum("ts,tsci,tsc->ti", w, basis, rhs)
        with np.errstate(all="ignore"):
            return np.nan_to_num(np.linalg.solve(A, b[..., None])[..., 0])

    eye = np.eye(3)
    base = np.concatenate([up[..., None, None] * eye, ((1.0 - S) * dv)[..., None, None] * eye], axis=-1)  # (T,S,3,6)
    if not grazing:
        x = solve(base, f_src - (S * dv)[..., None])
        return {"rho_d": np.clip(x[:, :3], *rho_bounds), "specular_color": np.clip(x[:, 3:6], 0.0, 1.0),
                "specular": np.ones((T, 1)), **shape}
    full = np.concatenate([base, np.broadcast_to((S * dv)[..., None, None], base.shape[:3] + (1,))], axis=-1)
    x = solve(full, f_src)
    a = np.clip(x[:, 3:6], 0.0, 1.0)
    cands = [np.concatenate([np.clip(x[:, :3], *rho_bounds), a,
                             np.clip(np.maximum(x[:, 6:7], a.max(axis=1, keepdims=True)), 0.0, 1.0)], axis=1)]
    flat = np.concatenate([up[..., None, None] * eye, dv[..., None, None] * eye], axis=-1)
    y = solve(flat, f_src)
    ya = np.clip(y[:, 3:6], 0.0, 1.0)
    cands.append(np.concatenate([np.clip(y[:, :3], *rho_bounds), ya, ya.max(axis=1, keepdims=True)], axis=1))
    costs = []
    for c in cands:
        model_f = np.einsum("tsci,ti->tsc", full, c)
        costs.append(np.sum(w[..., None] * (model_f - f_src) ** 2, axis=(1, 2)))
    x = np.where((costs[1] < costs[0])[:, None], cands[1], cands[0])
    s = x[:, 6:7]
    with np.errstate(all="ignore"):
        color = np.where(s > 0, np.clip(x[:, 3:6] / s, 0.0, 1.0), 0.0)
    return {"rho_d": x[:, :3], "specular_color": color, "specular": s, **shape}


#: The roughness grid of the isotropic start: α from 0.01 to 1 in 40 geometric steps (3.6 % apart in √α).
GRID_ALPHAS = tuple(np.geomspace(0.01, MAX_ALPHA, 40))


def _grid_start(target: SpecularGGX, f_src, ok, wi, wo, grazing: bool) -> tuple[dict, np.ndarray]:
    """Variable projection over :data:`GRID_ALPHAS`: for each α the magnitudes' linear least squares, per texel.

    The pairs are shared by every texel, so for a given α the design matrix (and its normal matrix A) is one
    for all of them: each texel costs a matrix product, not a fit.  The solution is projected onto the box
    (ρ_d ≥ 0, 0 ≤ s·F0c ≤ s ≤ 1) and scored exactly, ``‖f‖² − 2 xᵀb + xᵀAx``; the best α is refined by a
    parabola in log α through its neighbours.  Returns ``(start, cost)`` for ``(T, S)`` ``f_src`` and the
    ``(S, 3)`` pairs.
    """
    T = f_src.shape[0]
    n = 7 if grazing else 6
    S = _schlick(wi, wo)
    up = above_horizon(wi[None], wo[None])[0].astype(float)
    w = CosineWeighted.weight(wi, wo) ** 2
    f = f_src * ok[:, None, None]
    costs, solutions = [], []
    for a in GRID_ALPHAS:
        dv = target.lobe.eval(target._lobe({p.name: np.full((1, 1), a) for p in target.shape}, 1),
                              wi[None], wo[None])[0, :, 0]
        cols = np.zeros((wi.shape[0], 3, n))
        for c in range(3):
            cols[:, c, c], cols[:, c, 3 + c] = up, (1.0 - S) * dv
            if grazing:
                cols[:, c, 6] = S * dv
        target_f = f if grazing else f - (S * dv)[None, :, None]
        wc = cols * w[:, None, None]
        A = np.einsum("sci,scj->ij", wc, cols)
        A += (1e-9 * np.trace(A) + 1e-30) * np.eye(n)
        b = target_f.reshape(T, -1) @ wc.reshape(-1, n)  # (T, n)
        ff = np.einsum("tsc,s->t", target_f**2, w)

        def score(x, ff=ff, b=b, A=A):
            return ff - 2 * np.einsum("ti,ti->t", x, b) + np.einsum("ti,ij,tj->t", x, A, x)

        x = np.linalg.solve(A, b.T).T
        x[:, :3] = np.clip(x[:, :3], *target.parameters[0].bounds)
        x[:, 3:6] = np.clip(x[:, 3:6], 0.0, 1.0)
        if grazing:
            # where the free solution wants a grazing weight below its F0 (a source that does not brighten toward
            # grazing), the box's edge s = max F0 is better reached from the flat-Fresnel solution F = F0c s
            x[:, 6] = np.clip(np.maximum(x[:, 6], x[:, 3:6].max(axis=1)), 0.0, 1.0)
            flat = cols[..., :6].copy()
            flat[:, np.arange(3), 3 + np.arange(3)] = dv[:, None]
            wf = flat * w[:, None, None]
            Af = np.einsum("sci,scj->ij", wf, flat)
            Af += (1e-9 * np.trace(Af) + 1e-30) * np.eye(6)
            y = np.linalg.solve(Af, (f.reshape(T, -1) @ wf.reshape(-1, 6)).T).T
            y = np.concatenate([np.clip(y[:, :3], *target.parameters[0].bounds), np.clip(y[:, 3:6], 0.0, 1.0)], 1)
            y = np.concatenate([y, y[:, 3:6].max(axis=1, keepdims=True)], axis=1)
            cx, cy = score(x), score(y)
            x = np.where((cy < cx)[:, None], y, x)
        costs.append(score(x))
        solutions.append(x)
    cost = np.stack(costs, axis=1)  # (T, K)
    k = np.argmin(cost, axis=1)
    logs = np.log(np.asarray(GRID_ALPHAS))
    km, kp = np.clip(k - 1, 0, len(logs) - 1), np.clip(k + 1, 0, len(logs) - 1)
    c0, cm, cp = (np.take_along_axis(cost, i[:, None], 1)[:, 0] for i in (k, km, kp))
    curv = cm + cp - 2 * c0
    step = logs[1] - logs[0]
    with np.errstate(all="ignore"):
        shift = np.where((km != k) & (kp != k) & (curv > 0), 0.5 * step * (cm - cp) / curv, 0.0)
    alpha = np.exp(logs[k] + np.clip(np.nan_to_num(shift), -step, step))[:, None]
    x = np.stack(solutions, axis=1)[np.arange(T), k]
    s = x[:, 6:7] if grazing else np.ones((T, 1))
    with np.errstate(all="ignore"):
        color = np.where(s > 0, np.clip(x[:, 3:6] / s, 0.0, 1.0), 0.0)
    return {"rho_d": x[:, :3], "specular_color": color, "specular": s, "alpha": alpha}, c0


def _initial_guess(target, f_src, valid, wi, wo, source=None, grazing=True) -> dict[str, np.ndarray]:
    """Per texel, the best of the starting shapes (:func:`_shapes`) with the magnitudes solved linearly for each
    (the isotropic target: :func:`_grid_start`'s α, and the source's :func:`mapped_alpha`)."""
    T = f_src.shape[0]
    best, best_cost = None, np.full(T, np.inf)
    w = CosineWeighted.weight(wi, wo)[..., None] ** 2 * valid[..., None]
    isotropic = "alpha" in {p.name for p in target.shape}
    if isotropic:
        grid, _ = _grid_start(target, f_src, valid.any(axis=1), wi[0], wo[0], grazing)
        mapped = mapped_alpha(source or {})
        shapes = [{"alpha": grid["alpha"]}] + ([{"alpha": mapped}] if mapped is not None else [])
    else:
        shapes = _shapes(target, T, source or {})
    for shape in shapes:
        guess = _solve_magnitudes(target, shape, f_src, valid, wi, wo, grazing)
        with np.errstate(all="ignore"):
            cost = np.sum(w * (target.eval(guess, wi, wo) - f_src) ** 2, axis=(1, 2))
        best, best_cost = keep_lower(best, best_cost, guess, cost)
    assert best is not None, "there is always a shape to try"
    return best


def keep_lower(best, best_cost, cand, cost):
    """``(best, best_cost)`` with each texel taking ``cand`` (model-form parameters) where its ``cost`` is lower
    (a non-finite cost never is); ``best`` None: ``cand`` itself."""
    cost = np.where(np.isfinite(cost), cost, np.inf)
    if best is None:
        return cand, cost
    better = cost < best_cost
    return {k: np.where(better[:, None], cand[k], best[k]) for k in best}, np.where(better, cost, best_cost)


def _same_model(model, ggx) -> bool:
    return (model.name == ggx.name and getattr(model, "distribution", None) == getattr(ggx, "distribution", None)
            and [p.name for p in model.parameters] == [p.name for p in ggx.parameters])


def gltf_brdf(ggx, gltf: dict, wi: np.ndarray, wo: np.ndarray, anisotropic=None) -> np.ndarray:
    """glTF 2.0's metallic-roughness BRDF (Appendix B) with ``KHR_materials_specular``, ``(T, S, 3)``.

    ``gltf``: the :data:`GLTF_MAPS` per texel (linear; ``specular_color`` is the
    factor × texture product, ``specular`` the specularFactor).  ``wi``, ``wo``:
    shared ``(S, 3)`` pairs, or each texel's own ``(T, S, 3)`` (its samples' directions).  D·V comes from ``ggx`` (cook-torrance GGX with F0 = 1, ρ_d = 0),
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
    s5 = _schlick(wi, wo)[..., None]  # (S, 1) or (T, S, 1)
    f0 = np.minimum(DIELECTRIC_F0 * spec_col, 1.0)[:, None, :]
    fr = f0 + (1.0 - f0) * s5
    dielectric = (1.0 - s * fr.max(axis=-1, keepdims=True)) * bc[:, None, :] / np.pi + s * fr * dv
    metal = dv * (bc[:, None, :] + (1.0 - bc[:, None, :]) * s5)
    up = ((wi[..., 2] > 0) & (wo[..., 2] > 0))[..., None]
    return np.where(up, (1.0 - m) * dielectric + m * metal, 0.0)


def to_gltf_pbr(model, params: dict, ggx, *, starts: int = 1, iterations: int = 8, anisotropic=None,
                flag_error: float = FLAG_ERROR, max_theta_deg: float = VIEW_THETA_DEG):
    """Refit to GGX and read the fit as glTF metallic-roughness (+ KHR_materials_specular) per texel.

    ``params``: ``{name: (T, C)}`` of ``model``; ``ggx``: :func:`ggx_model`;
    ``anisotropic``: :func:`anisotropic_model` to also try ``KHR_materials_anisotropy``
    (only for a model that may be anisotropic: its ``anisotropic`` is not False).
    Returns ``(gltf, error)``: ``gltf`` holds the :data:`GLTF_MAPS` as ``(T, C)``
    linear values (``specular_color`` = F0c/0.04, may exceed 1: the writer folds
    it into ``specularColorFactor`` × texture; ``anisotropy`` = direction x, y and
    strength), ``error`` ``(T,)`` the held-out
    cosine-weighted relative RMS of glTF's BRDF against the source (1 for invalid texels).
    """
    refit = partial(to_ggx, model, params, starts=starts, iterations=iterations, flag_error=flag_error,
                    max_theta_deg=max_theta_deg)
    fits = [(refit(ggx), None)]
    if anisotropic is not None and getattr(model, "anisotropic", True):
        fits.append((refit(anisotropic), anisotropic))
    T = fits[0][0]["error"].shape[0]
    gltf = {k: np.zeros((T, c)) for k, c in GLTF_MAPS.items()}
    error = np.ones(T)
    wi, wo = direction_pairs(max_theta_deg=max_theta_deg)
    hi_wi, hi_wo = direction_pairs(held_out=True, max_theta_deg=max_theta_deg)
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
    """The better of a fit's two glTF readings per texel, dielectric or metal, and its error on ``wi, wo``."""
    T = fit["specular"].shape[0]
    s, color = fit["specular"], fit["specular_color"]
    if anisotropic is None:
        rough, aniso = np.clip(np.sqrt(np.maximum(fit["alpha"], 0.0)), 0.0, 1.0), np.broadcast_to(ISOTROPIC, (T, 3))
    else:  # KHR_materials_anisotropy: α_b = roughness², α_t = mix(α_b, 1, strength²), direction (cos φ, sin φ)
        c = anisotropic.canonical(fit)
        ab, at = np.clip(c["alpha_b"], 0.0, 1.0), np.clip(c["alpha_t"], 0.0, 1.0)
        rough = np.sqrt(ab)
        with np.errstate(all="ignore"):
            strength = np.sqrt(np.clip(np.nan_to_num((at - ab) / (1.0 - ab)), 0.0, 1.0))
        aniso = np.concatenate([np.cos(c["phi"]), np.sin(c["phi"]), strength], axis=1)
    ones = np.ones((T, 1))
    # dielectric reading: s is specularFactor, F0c = 0.04 specularColor; base colour solved linearly (f is affine in it)
    diel = {"base_color": np.zeros((T, 3)), "metallic": np.zeros((T, 1)), "roughness": rough, "specular": s,
            "specular_color": np.clip(color / DIELECTRIC_F0, 0.0, 1.0 / DIELECTRIC_F0), "anisotropy": aniso}
    offset = gltf_brdf(ggx, diel, wi, wo, anisotropic)
    basis = gltf_brdf(ggx, {**diel, "base_color": np.ones((T, 3))}, wi, wo, anisotropic) - offset
    w = _cos_weight(wi, wo)[None, :, None]
    with np.errstate(all="ignore"):
        bc = np.sum(w * basis * (f_src - offset), axis=1) / np.sum(w * basis * basis, axis=1)
    diel["base_color"] = np.clip(np.nan_to_num(bc), 0.0, 1.0)
    # metal reading: F runs from the base colour to 1 (glTF's metal has no specular weight)
    metal = {"base_color": np.clip(s * color, 0.0, 1.0), "metallic": ones, "roughness": rough, "specular": ones,
             "specular_color": ones.repeat(3, axis=1), "anisotropy": aniso}
    e_diel = relative_error(gltf_brdf(ggx, diel, wi, wo, anisotropic), f_src, wi, wo)
    e_metal = relative_error(gltf_brdf(ggx, metal, wi, wo, anisotropic), f_src, wi, wo)
    # the metal reading is what core glTF (no extension) shows right: preferred unless it costs more than 1 %
    use_metal = e_metal <= e_diel + METAL_PREFERENCE
    reading = {k: np.where(use_metal[:, None], metal[k], diel[k]) for k in GLTF_MAPS}
    return reading, np.where(use_metal, e_metal, e_diel)


def _gltf_batch(model, params, ggx, fits, wi, wo, hi_wi, hi_wo):
    T = fits[0][0]["specular"].shape[0]
    f_src, ok = _prepare(model, params, wi, wo)
    anisotropic = None
    gltf: dict[str, np.ndarray] | None = None
    err: np.ndarray | None = None
    for fit, target in fits:  # the isotropic reading, then (if given) the anisotropic one where it gains enough
        ok &= fit["valid"]
        reading, e = _readings(ggx, fit, target, f_src, wi, wo)
        if gltf is None or err is None:  # the first reading (both are set together)
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
    """Lazy :func:`to_ggx` over ``(V, U, C)`` dask maps: the :data:`GGX_MAPS` (``error`` ``(V, U, 1)``), float32."""

    def fn(model, flat, **kw):
        r = to_ggx(model, flat, ggx, **kw)
        return {**r, "error": r["error"][:, None]}

    return _blocks(fn, GGX_MAPS, model, params, **kw)


def to_gltf_pbr_blocks(model, params: dict, ggx, **kw) -> dict:
    """Lazy :func:`to_gltf_pbr` over ``(V, U, C)`` dask maps: the :data:`GLTF_MAPS` and ``error`` ``(V, U, 1)``, float32."""

    def fn(model, flat, **kw):
        g, e = to_gltf_pbr(model, flat, ggx, **kw)
        return {**g, "error": e[:, None]}

    return _blocks(fn, {**GLTF_MAPS, "error": 1}, model, params, **kw)


#: Roughness values α the fit from samples starts among (per texel, magnitudes solved linearly for each).
SAMPLE_START_ALPHAS = tuple(np.geomspace(0.01, MAX_ALPHA, 16))


def sample_error(f: np.ndarray, f_r: np.ndarray, valid: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Per texel, ``sqrt(Σ w |f − f_r|²) / sqrt(Σ w |f_r|²)`` over its valid samples, w = cos θ_i cos θ_o, ``(T,)``.

    ``f``, ``f_r``: ``(T, S, 3)``; ``valid``: ``(T, S)``; ``wi``, ``wo``: ``(T, S, 3)``.  The measure of
    :func:`relative_error` on measured samples (no held-out split: the samples are the material itself).
    A texel without valid samples, or whose samples are all 0 while ``f`` is not, gets 1.
    """
    w = (ProjectedWeighted.weight(wi, wo) ** 2 * valid)[..., None]
    with np.errstate(all="ignore"):
        num = np.sqrt(np.sum(w * (f - f_r) ** 2, axis=(1, 2)))
        den = np.sqrt(np.sum(w * f_r**2, axis=(1, 2)))
        err = num / den
    tiny = den <= 1e-12
    err = np.where(tiny, np.where((num <= 1e-12) & valid.any(axis=1), 0.0, 1.0), err)
    return np.where(np.isfinite(err), err, 1.0)


def samples_to_gltf(f_r: np.ndarray, valid: np.ndarray, wi: np.ndarray, wo: np.ndarray, ggx, *, starts: int = 1,
                    iterations: int = 8, max_theta_deg: float = VIEW_THETA_DEG) -> tuple[dict, np.ndarray]:
    """Fit glTF's GGX (:class:`SpecularGGX`) to each texel's reflectance samples and read it as glTF.

    What a user exporting a capture to glTF wants: the format's model fitted to what was measured, not to
    another model's fit of it.  ``f_r`` ``(T, S, 3)`` sr⁻¹, ``valid`` ``(T, S)``, ``wi``, ``wo`` ``(T, S, 3)``
    (the samples' directions, :func:`sbrdf_core.geometry.tile_directions`); samples beyond
    ``max_theta_deg`` from the normal are left out, as the conversion leaves those directions out.  Per
    texel: the best of :data:`SAMPLE_START_ALPHAS` with ρ_d, s·F0c and s solved linearly, refined by the
    shared LM, α kept at or above what the samples resolve (``Limits.min_roughness``, the Fit node's sharpness
    bound) (:func:`sbrdf_lib.lm.fit_model`) on the cos θ_i cos θ_o weighted least squares
    (:class:`ProjectedWeighted`), then read as glTF's dielectric or metal the way the conversion reads its
    fit (step 4 of the module docstring).  Returns ``(gltf, error)``: the :data:`GLTF_MAPS` ``(T, C)`` and
    :func:`sample_error` of glTF's BRDF against the samples, ``(T,)``.  A texel without valid samples gets
    the defaults (black, roughness 1) and error 1.

    >>> import numpy as np
    >>> from sbrdf_lib.convert import ggx_model, samples_to_gltf
    >>> ct = ggx_model()
    >>> wi, wo = (np.broadcast_to(d, (1,) + d.shape) for d in direction_pairs())
    >>> truth = {"rho_d": np.full((1, 3), 0.1), "f0": np.full((1, 3), 0.04), "alpha": np.array([[0.1]])}
    >>> g, e = samples_to_gltf(ct.eval(truth, wi, wo), np.ones(wi.shape[:2], bool), wi, wo, ct)
    >>> round(float(g["roughness"][0, 0]) ** 2, 3), bool(e[0] < 0.01)
    (0.1, True)
    """
    from sbrdf_core.constraints import angular_resolution
    from sbrdf_core.nodes.fit import usable
    from sbrdf_core.types import Limits
    from sbrdf_lib.lm import fit_model

    target = SpecularGGX(ggx)
    wi, wo = np.asarray(wi, np.float64), np.asarray(wo, np.float64)
    f_r, valid = usable(np.asarray(f_r), np.asarray(valid, bool), np.float64)
    limit = np.cos(np.radians(max_theta_deg))
    valid = valid & (wi[..., 2] >= limit) & (wo[..., 2] >= limit)
    f_r = np.where(valid[..., None], f_r, 0.0)
    T = f_r.shape[0]
    pwi, pwo = direction_pairs(max_theta_deg=max_theta_deg)
    gltf = {k: np.zeros((T, c)) for k, c in GLTF_MAPS.items()}
    error = np.ones(T)
    for b in range(0, T, BATCH):
        sl = slice(b, min(b + BATCH, T))
        f, v, a, o = f_r[sl], valid[sl], wi[sl], wo[sl]
        n = f.shape[0]
        w = ProjectedWeighted.weight(a, o)[..., None]
        # no lobe sharper than the samples resolve (the Fit node's sharpness bound): between the samples a
        # sharper one is unmeasured, and renders as sparkling texels
        floor = np.clip(np.asarray(Limits(resolution=angular_resolution(a, o, v)).min_roughness(), np.float64)
                        .reshape(n, 1), SAMPLE_START_ALPHAS[0], MAX_ALPHA)
        best, best_cost = None, np.full(n, np.inf)
        for alpha in SAMPLE_START_ALPHAS:
            guess = _solve_magnitudes(target, {"alpha": np.maximum(alpha, floor)}, f, v, a, o, True,
                                      weight=ProjectedWeighted)
            with np.errstate(all="ignore"):
                cost = np.sum((w * v[..., None] * (target.eval(guess, a, o) - f)) ** 2, axis=(1, 2))
            best, best_cost = keep_lower(best, best_cost, guess, cost)
        assert best is not None
        fitted = best
        if iterations > 0:
            form = target.fit_form()
            fitted, _, _ = fit_model(ProjectedWeighted(form), f * w, v, a, o, initial=form.from_model(best),
                                     starts=starts, iterations=iterations)
            sharp = np.asarray(fitted["alpha"]) < floor
            if sharp.any():  # the LM went past the bound: the magnitudes again at the bound
                bounded = _solve_magnitudes(target, {"alpha": np.maximum(fitted["alpha"], floor)}, f, v, a, o, True,
                                            weight=ProjectedWeighted)
                fitted = {k: np.where(sharp, bounded[k], fitted[k]) for k in fitted}
        ok = np.asarray(v.any(axis=1))  # (n,): an array, which the stubs cannot tell from a scalar
        defaults = target.defaults(n)
        fit = {p.name: np.clip(np.where(ok[:, None], np.nan_to_num(np.asarray(fitted[p.name], np.float64)),
                                        defaults[p.name]), *p.bounds) for p in target.parameters}
        # the glTF reading that best reproduces the fitted lobe over the hemisphere (the conversion's pairs)
        reading, _ = _readings(ggx, fit, None, _eval(target, fit, pwi, pwo), pwi, pwo)
        default = {"base_color": np.zeros((n, 3)), "metallic": np.zeros((n, 1)), "roughness": np.ones((n, 1)),
                   "specular": np.ones((n, 1)), "specular_color": np.ones((n, 3)),
                   "anisotropy": np.broadcast_to(ISOTROPIC, (n, 3))}
        black = ok & (np.abs(f).max(axis=(1, 2)) == 0.0)
        for k in GLTF_MAPS:
            gltf[k][sl] = np.where(ok[:, None], reading[k], default[k])
        for k in ("base_color", "metallic", "specular"):
            gltf[k][sl] = np.where(black[:, None], 0.0, gltf[k][sl])
        e = sample_error(gltf_brdf(ggx, {k: gltf[k][sl] for k in GLTF_MAPS}, a, o), f, v, a, o)
        error[sl] = np.where(ok, e, 1.0)
    return gltf, error


def samples_to_gltf_blocks(f_r, valid, light_pos: np.ndarray, camera_pos: np.ndarray, texels: tuple[int, int],
                           size_mm: tuple[float, float], ggx, **kw) -> dict:
    """Lazy :func:`samples_to_gltf` over a SampledReflectance's ``f_r`` ``(V, U, P, 3)`` and ``valid`` ``(V, U, P)``
    dask arrays (all poses of a tile in one chunk): the :data:`GLTF_MAPS` and ``error`` ``(V, U, C)``, float32,
    chunked as the samples' tiles.  Directions come from the poses' ``light_pos``, ``camera_pos`` ``(P, 3)``."""
    import dask.array as da

    from sbrdf_core.geometry import tile_directions

    names = {**GLTF_MAPS, "error": 1}
    K = sum(names.values())
    light_pos, camera_pos = np.asarray(light_pos, np.float64), np.asarray(camera_pos, np.float64)
    (n_u, n_v), (size_x, size_y) = texels, size_mm  # pairs, also when given as lists

    def block(f, v, block_info=None):
        (v0, v1), (u0, u1) = block_info[0]["array-location"][:2]
        wi, _, wo = tile_directions((n_u, n_v), (size_x, size_y), (v0, v1), (u0, u1), light_pos, camera_pos)
        V, U = f.shape[:2]
        g, e = samples_to_gltf(f.reshape(V * U, -1, 3), v.reshape(V * U, -1), wi, wo, ggx, **kw)
        return np.concatenate([np.asarray(g[k], np.float32).reshape(V, U, -1) for k in GLTF_MAPS]
                              + [e.astype(np.float32).reshape(V, U, 1)], axis=-1)

    f_r = da.asarray(f_r).rechunk({2: -1, 3: -1})
    valid = da.asarray(valid).rechunk({2: -1})
    stacked = da.map_blocks(block, f_r, valid[..., None], drop_axis=[3], chunks=f_r.chunks[:2] + ((K,),),
                            dtype=np.float32)
    out, k = {}, 0
    for name, c in names.items():
        out[name] = stacked[..., k:k + c]
        k += c
    return out

