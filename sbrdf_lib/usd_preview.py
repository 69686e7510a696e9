"""UsdPreviewSurface's BRDF, and the conversion of any model's per-texel BRDF to it.

UsdPreviewSurface (the UsdPreviewSurface specification, openusd.org; its
reference implementation is Storm's ``previewSurface.glslfx``, whose
``evaluateLight`` this module follows term by term) shades a point light with
``f_r cos θ_i`` where, in the *specular workflow* (``useSpecularWorkflow`` 1)::

    f_r = d/π (1 − F) + F Q(r) + c (R + (1 − R) S) Q(r_c)
    F   = F0 + (1 − F0) S,   S = (1 − ω_o·h)⁵             (Schlick, F90 = 1: "edge color is assumed white")
    Q(r) = D G / (4 cos θ_i cos θ_o + ε)
    D   = (α² + ε) / (π ((n·h)² (α² − 1) + 1)²),  α = r²   (GGX)
    G   = g(cos θ_i) g(cos θ_o),  g(x) = x / (x (1 − k) + k),  k = α/2   (Smith–Schlick, separable)

with ``d`` = diffuseColor, ``F0`` = specularColor, ``r`` = roughness,
``c`` = clearcoat, ``r_c`` = clearcoatRoughness, ``R`` = ((1 − ior)/(1 + ior))²
(the clearcoat's normal-incidence Fresnel; its colour is white) and ε = 0.001
(Storm's; it matters for the sharpest lobes: at r = 0.18, α² + ε is 3 % above α²).

Why a model of its own: the first specular lobe's Fresnel always rises to 1
at grazing.  A measured lobe that does not brighten toward grazing (every
Lafortune or Phong fit; the README demo's GGX reading has s ≈ 0.005, F0c ≈ 0.75)
can only follow it spread flat (roughness at 1), which exports a glossy
material matte.  The clearcoat lobe's Fresnel runs from c R to c: with R from
``ior`` it is glTF's specular weight and colour (s = c, F0c = R) in grey, so
the gloss goes there, and the first lobe stays the rough, grazing-only term
UsdPreviewSurface always has.  The conversion fits this BRDF itself (the
cosine-weighted objective of :mod:`sbrdf_lib.convert` and its LM) so the error
reported is the error of what a USD renderer shows.

:class:`PreviewSurface` is the model; :func:`to_preview_surface` converts,
per texel; :func:`to_preview_surface_blocks` over dask maps.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.brdf import BRDFModel, LogFitForm, ModelParameter, above_horizon

from .convert import (
    BATCH,
    VIEW_THETA_DEG,
    CosineWeighted,
    _blocks,
    _eval,
    _prepare,
    direction_pairs,
    keep_lower,
    relative_error,
    to_ggx,
)

__all__ = ["EPSILON", "MAX_CLEARCOAT_F0", "USD_MAPS", "PreviewSurface", "ior_of", "to_preview_surface",
           "to_preview_surface_blocks"]

#: Storm's ε in D's numerator and the 4 cos θ_i cos θ_o denominator.
EPSILON = 1e-3
#: Largest clearcoat normal-incidence Fresnel R the conversion uses: ior = (1 + √R)/(1 − √R) ≤ 19.
MAX_CLEARCOAT_F0 = 0.81
#: Smallest roughness fitted (Storm clamps at 0.001; below 0.03 no sampled direction set resolves the lobe).
MIN_ROUGHNESS = 0.03
#: The per-texel maps :func:`to_preview_surface` returns and their channels.
USD_MAPS = {"diffuse_color": 3, "specular_color": 3, "roughness": 1, "clearcoat": 1, "clearcoat_f0": 1,
            "clearcoat_roughness": 1, "error": 1}
_CLEARCOAT = ("clearcoat", "clearcoat_f0", "clearcoat_roughness")


def ior_of(clearcoat_f0: np.ndarray) -> np.ndarray:
    """The ``ior`` whose ((1 − ior)/(1 + ior))² is ``clearcoat_f0``: (1 + √R)/(1 − √R).

    >>> float(ior_of(np.array(0.04)))
    1.5
    """
    r = np.sqrt(np.clip(clearcoat_f0, 0.0, MAX_CLEARCOAT_F0))
    return (1.0 + r) / (1.0 - r)


def _q(r, nl, ne, nh):
    """Q(r) = D G / (4 cos θ_i cos θ_o + ε) and ∂Q/∂r, shaped like ``nl`` (``r`` broadcast against it)."""
    a = r * r
    a2 = a * a
    u = nh * nh * (a2 - 1.0) + 1.0
    D = (a2 + EPSILON) / (np.pi * u * u)
    dD = (1.0 / (np.pi * u * u) - 2.0 * (a2 + EPSILON) * nh * nh / (np.pi * u**3)) * 4.0 * r**3
    k = 0.5 * a
    gi, ge = nl * (1.0 - k) + k, ne * (1.0 - k) + k
    G = nl / gi * ne / ge
    # ∂g/∂k = −x (1 − x)/(x (1 − k) + k)², ∂k/∂r = r
    dG = -(nl * (1.0 - nl) / gi**2 * ne / ge + ne * (1.0 - ne) / ge**2 * nl / gi) * r
    den = 4.0 * nl * ne + EPSILON
    return D * G / den, (dD * G + D * dG) / den


class PreviewSurface(BRDFModel):
    """UsdPreviewSurface's specular workflow with its clearcoat lobe (module docstring), per texel.

    Parameters: ``diffuse_color`` d (3), ``specular_color`` F0 (3), ``roughness`` r,
    ``clearcoat`` c, ``clearcoat_f0`` R (from ``ior``: :func:`ior_of`) and
    ``clearcoat_roughness`` r_c, each in the range USD reads.

    >>> import numpy as np
    >>> m = PreviewSurface()
    >>> p = {**m.defaults(1), "diffuse_color": np.full((1, 3), 0.5)}
    >>> d = np.array([[[0.0, 0.0, 1.0]]])
    >>> m.eval(p, d, d).shape
    (1, 1, 3)
    """

    name = "usd-preview-surface"
    anisotropic = False
    suggested_starts = 1

    def __init__(self):
        self.parameters = (
            ModelParameter("diffuse_color", 3, (0.0, 1.0), (0.02, 0.9), 0.18, magnitude=True, unit="1",
                           doc="diffuseColor: the Lambert albedo (f_r = d/π before the Fresnel dimming)"),
            ModelParameter("specular_color", 3, (0.0, 1.0), (0.0, 0.1), 0.04, magnitude=True, unit="1",
                           doc="specularColor: the first lobe's Fresnel at normal incidence (1 at grazing)"),
            ModelParameter("roughness", 1, (MIN_ROUGHNESS, 1.0), (0.1, 1.0), 0.5, unit="1",
                           doc="roughness: the first lobe's √α"),
            ModelParameter("clearcoat", 1, (0.0, 1.0), (0.0, 1.0), 0.0, magnitude=True, unit="1",
                           doc="clearcoat: the second (white) lobe's weight, its Fresnel at grazing"),
            ModelParameter("clearcoat_f0", 1, (0.0, MAX_CLEARCOAT_F0), (0.02, 0.8), 0.04, unit="1",
                           doc="((1 − ior)/(1 + ior))²: the clearcoat's Fresnel at normal incidence before its weight"),
            ModelParameter("clearcoat_roughness", 1, (MIN_ROUGHNESS, 1.0), (0.05, 1.0), 0.3, unit="1",
                           doc="clearcoatRoughness: the second lobe's √α"),
        )

    @staticmethod
    def _terms(params, wi, wo):
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        nl, ne = np.clip(wi[..., 2], 1e-6, 1.0), np.clip(wo[..., 2], 1e-6, 1.0)
        nh = np.clip(h[..., 2], 0.0, 1.0)
        S = (1.0 - np.clip(np.sum(wo * h, axis=-1), 0.0, 1.0)) ** 5
        q, dq = _q(np.asarray(params["roughness"])[:, :1], nl, ne, nh)
        qc, dqc = _q(np.asarray(params["clearcoat_roughness"])[:, :1], nl, ne, nh)
        return S, q, dq, qc, dqc

    def eval(self, params, wi, wo):
        S, q, _, qc, _ = self._terms(params, wi, wo)
        d = np.asarray(params["diffuse_color"])[:, None, :] / np.pi
        f0 = np.asarray(params["specular_color"])[:, None, :]
        c, R = np.asarray(params["clearcoat"])[:, None, :1], np.asarray(params["clearcoat_f0"])[:, None, :1]
        F = f0 + (1.0 - f0) * S[..., None]
        f = d * (1.0 - F) + F * q[..., None] + c * (R + (1.0 - R) * S[..., None]) * qc[..., None]
        return np.where(above_horizon(wi, wo)[..., None], f, 0.0)

    def jacobian(self, params, wi, wo):
        S, q, dq, qc, dqc = self._terms(params, wi, wo)
        S3 = S[..., None]
        d = np.asarray(params["diffuse_color"])[:, None, :] / np.pi
        f0 = np.asarray(params["specular_color"])[:, None, :]
        c, R = np.asarray(params["clearcoat"])[:, None, :1], np.asarray(params["clearcoat_f0"])[:, None, :1]
        F = f0 + (1.0 - f0) * S3
        up = above_horizon(wi, wo)[..., None].astype(float)
        eye = np.eye(3)
        cols = [((1.0 - F) / np.pi * eye[k]) for k in range(3)]
        cols += [((1.0 - S3) * (q[..., None] - d) * eye[k]) for k in range(3)]
        cols += [F * dq[..., None]]
        cc = R + (1.0 - R) * S3
        cols += [np.broadcast_to(cc * qc[..., None], F.shape), np.broadcast_to(c * (1.0 - S3) * qc[..., None], F.shape),
                 np.broadcast_to(c * cc * dqc[..., None], F.shape)]
        return np.stack([col * up for col in cols], axis=-1)

    def fit_form(self) -> BRDFModel:
        """The roughnesses fitted as their logarithms (they span decades, as GGX's α does)."""
        return LogFitForm(self, ("roughness", "clearcoat_roughness"))


def _starts(model: PreviewSurface, params, ggx, kw) -> list[dict]:
    """Two readings of the GGX conversion (:func:`sbrdf_lib.convert.to_ggx`) as starting points.

    The gloss in the clearcoat (its weight c = s, R = mean F0c, r_c = √α; the first lobe rough and dark), and
    the first lobe alone (``grazing`` False: F0 = s F0c, r = √α, no clearcoat).
    """
    weighted = to_ggx(model, params, ggx, grazing=True, iterations=0, **kw)  # the grid's start: refined below
    flat = to_ggx(model, params, ggx, grazing=False, iterations=0, **kw)
    T = weighted["alpha"].shape[0]
    ones, zeros = np.ones((T, 1)), np.zeros((T, 1))
    coat = {"diffuse_color": np.clip(np.pi * weighted["rho_d"], 0.0, 1.0), "specular_color": np.zeros((T, 3)),
            "roughness": ones, "clearcoat": weighted["specular"],
            "clearcoat_f0": np.clip(weighted["specular_color"].mean(axis=1, keepdims=True), 0.0, MAX_CLEARCOAT_F0),
            "clearcoat_roughness": np.clip(np.sqrt(weighted["alpha"]), MIN_ROUGHNESS, 1.0)}
    lobe = {"diffuse_color": np.clip(np.pi * flat["rho_d"], 0.0, 1.0), "specular_color": flat["f0"],
            "roughness": np.clip(np.sqrt(flat["alpha"]), MIN_ROUGHNESS, 1.0), "clearcoat": zeros,
            "clearcoat_f0": np.full((T, 1), 0.04), "clearcoat_roughness": np.full((T, 1), 0.3)}
    return [coat, lobe]


def to_preview_surface(model, params: dict, ggx, *, clearcoat: bool = True, starts: int = 1, iterations: int = 8,
                       max_theta_deg: float = VIEW_THETA_DEG) -> dict[str, np.ndarray]:
    """Fit UsdPreviewSurface (:class:`PreviewSurface`) to ``model``'s per-texel BRDF, ``{name: (T, C)}``.

    Refines each of two readings of the GGX conversion (:func:`_starts`) on the cosine-weighted objective
    of :mod:`sbrdf_lib.convert` with the shared LM and keeps, per texel, the better on the fitting pairs.  ``clearcoat`` False: the
    clearcoat is held at 0 (the specular workflow's one lobe).  Returns the :data:`USD_MAPS` as ``(T, C)``;
    ``error`` is the held-out cosine-weighted relative RMS of UsdPreviewSurface's BRDF against the source
    (1 for texels whose source is not finite).

    >>> import numpy as np
    >>> from sbrdf_lib.convert import ggx_model
    >>> ct = ggx_model()
    >>> p = {"rho_d": np.full((1, 3), 0.1), "f0": np.full((1, 3), 0.04), "alpha": np.array([[0.1]])}
    >>> r = to_preview_surface(ct, p, ct)
    >>> sorted(r)[:3], r["error"].shape
    (['clearcoat', 'clearcoat_f0', 'clearcoat_roughness'], (1, 1))
    """
    from sbrdf_lib.lm import fit_model

    target = PreviewSurface()
    wi, wo = direction_pairs(max_theta_deg=max_theta_deg)
    hi_wi, hi_wo = direction_pairs(held_out=True, max_theta_deg=max_theta_deg)
    T = np.asarray(params[model.parameters[0].name]).shape[0]
    out = {k: np.zeros((T, c)) for k, c in USD_MAPS.items()}
    kw = dict(max_theta_deg=max_theta_deg)
    for s in range(0, T, BATCH):
        sl = slice(s, min(s + BATCH, T))
        sub = {p.name: np.asarray(params[p.name], np.float64)[sl] for p in model.parameters}
        f_src, ok = _prepare(model, sub, wi, wo)
        n, S = f_src.shape[:2]
        bwi, bwo = np.broadcast_to(wi, (n, S, 3)), np.broadcast_to(wo, (n, S, 3))
        w = CosineWeighted.weight(wi, wo)[None, :, None] ** 2
        form = target.fit_form()
        valid = np.broadcast_to(ok[:, None], (n, S)).copy()
        sw = CosineWeighted.weight(bwi, bwo)[..., None]
        best, best_cost = None, np.full(n, np.inf)
        for cand in _starts(model, sub, ggx, kw):  # each start refined, the better kept: neither wins everywhere
            if not clearcoat:
                cand = {**cand, "clearcoat": np.zeros((n, 1))}
            if iterations > 0:
                cand, _, _ = fit_model(CosineWeighted(form), f_src * sw, valid, bwi, bwo,
                                       initial=form.from_model(cand), starts=starts, iterations=iterations,
                                       fixed=() if clearcoat else ("clearcoat",))
            with np.errstate(all="ignore"):
                cost = np.sum(w * (_eval(target, cand, wi, wo) - f_src) ** 2, axis=(1, 2))
            best, best_cost = keep_lower(best, best_cost, cand, cost)
        assert best is not None
        fitted = best
        defaults = target.defaults(n)
        res = {p.name: np.clip(np.where(ok[:, None], np.nan_to_num(np.asarray(fitted[p.name], np.float64)),
                                        defaults[p.name]), *p.bounds) for p in target.parameters}
        if not clearcoat:
            res["clearcoat"] = np.zeros((n, 1))
        hi_src, hi_ok = _prepare(model, sub, hi_wi, hi_wo)
        err = relative_error(_eval(target, res, hi_wi, hi_wo), hi_src, hi_wi, hi_wo)
        res["error"] = np.where(ok & hi_ok, err, 1.0)[:, None]
        for k in USD_MAPS:
            out[k][sl] = res[k]
    return out


def to_preview_surface_blocks(model, params: dict, ggx, **kw) -> dict:
    """Lazy :func:`to_preview_surface` over ``(V, U, C)`` dask maps: the :data:`USD_MAPS`, float32."""
    return _blocks(to_preview_surface, USD_MAPS, model, params, ggx=ggx, **kw)
