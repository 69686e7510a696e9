"""Rendering with a shading map, renderer-independent NumPy (seed 002 §4, Eq 2–3, Fig 6).

Per pixel, with local directions ω_i, ω_o (+z the normal) and texture
coordinates uv:

    r = σ · f_r(ω_o, ω_i) · cos θ_i          (Eq 2, any BRDF model, global parameters)
    L_o = S(uv, r) · E                       (point light of irradiance E at normal incidence)
    L_o = ∫ S(uv, r(ω_o, ω_i)) L_i(ω_i) dω_i (Eq 3, environment lighting)

``S`` looks the shading map up at layer ``r / a_max · (N − 1)``, trilinearly
(bilinear in uv with wrap-around, linear between slices), per colour
channel.  Above ``a_max`` it either clamps to the brightest slice or scales
the brightest slice by ``r / a_max`` (§4).  From compressed data it is
``k_s · (r / a_max)^K`` with k_s and K interpolated bilinearly in uv, as a
GPU's ``sampler2D`` does.

The four lookups compared in the paper's Fig 6 (``variant``):

==============  ==========================================================================
``texture``     one slice as a texture: ``S_t / avg_t · r · E`` (t = ``texture_slice``)
``radiance``    lookup by the outgoing radiance: ``S(r · E)`` (outside the integral)
``angle``       lookup by the angle of incidence: ``S(a(θ_i)) / a(θ_i) · r · E``, a(θ) the
                acquired images' average at that elevation (:func:`angle_table`)
``r``           the paper's lookup by r: ``S(r) · E``
==============  ==========================================================================
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

VARIANTS = ("texture", "radiance", "angle", "r")
ABOVE_MAX = ("clamp", "scale")
#: Entries of the a(θ) table, one per degree 0..90 (shared with the GLSL uniform array).
ANGLE_TABLE_SIZE = 91


@dataclass
class ShadingData:
    """Shading-map data for rendering: the full stack or the compressed k_s, K maps.

    Parameters
    ----------
    a_max
        Largest acquired average (BRDF times cosine), sr⁻¹.
    slices
        ``(N, V, U, C)`` shading map, or ``None`` when compressed.
    k_s, exponent
        ``(V, U, C)`` power-function parameters (Eq 4), or ``None`` for the full stack.
    n_slices
        N (needed for compressed data too: it fixes the texture variant's slice average).
    image_average, theta_i_deg
        ``(P,)`` averages and light elevations of the acquired images (the ``angle`` variant).
    """

    a_max: float
    n_slices: int
    slices: np.ndarray | None = None
    k_s: np.ndarray | None = None
    exponent: np.ndarray | None = None
    image_average: np.ndarray | None = None
    theta_i_deg: np.ndarray | None = None

    def __post_init__(self):
        if (self.slices is None) == (self.k_s is None or self.exponent is None):
            raise ValueError("ShadingData: give either slices (full stack) or k_s and exponent (compressed)")
        if not (np.isfinite(self.a_max) and self.a_max > 0):
            raise ValueError(f"ShadingData: a_max must be positive and finite, got {self.a_max}")

    @property
    def compressed(self) -> bool:
        return self.slices is None

    @classmethod
    def from_artifacts(cls, shading_map=None, compressed=None) -> ShadingData:
        """From an opened ``ShadingMap`` artifact, a ``PowerShadingMap`` one, or both (compressed wins)."""
        src = compressed if compressed is not None else shading_map
        if src is None:
            raise ValueError("ShadingData.from_artifacts: give a ShadingMap or a PowerShadingMap artifact")
        extra = {}
        if shading_map is not None:
            extra = {"image_average": shading_map.read("image_average"), "theta_i_deg": shading_map.read("theta_i_deg")}
        elif "image_average" in src.attrs:
            extra = {"image_average": np.asarray(src.attrs["image_average"]), "theta_i_deg": np.asarray(src.attrs["theta_i_deg"])}
        if compressed is not None:
            return cls(float(src.attrs["a_max"]), int(src.attrs["slices"]), k_s=compressed.read("k_s"),
                       exponent=compressed.read("exponent"), **extra)
        return cls(float(src.attrs["a_max"]), int(src.attrs["slices"]), slices=shading_map.read("slices"), **extra)


def angle_table(data: ShadingData) -> np.ndarray:
    """a(θ) at θ = 0, 1, …, 90°: the acquired averages interpolated over elevation.

    Beyond the acquired range a(θ) is held constant towards the normal and falls linearly
    to 0 at the horizon (the black image of the linearization).
    """
    if data.image_average is None or data.theta_i_deg is None:
        raise ValueError("the 'angle' lookup needs the acquired images' averages and elevations (image_average, theta_i_deg)")
    th = np.asarray(data.theta_i_deg, np.float64)
    a = np.asarray(data.image_average, np.float64)
    keep = np.isfinite(th) & np.isfinite(a) & (th < 90)
    th, a = th[keep], a[keep]
    order = np.argsort(th)
    return np.interp(np.arange(ANGLE_TABLE_SIZE, dtype=np.float64), np.append(th[order], 90.0), np.append(a[order], 0.0))


def _bilinear_setup(uv: np.ndarray, V: int, U: int):
    """Corner indices and weights of a wrap-around bilinear lookup at texel centres (i + 0.5) / U."""
    fu = np.asarray(uv[..., 0], np.float64) * U - 0.5
    fv = np.asarray(uv[..., 1], np.float64) * V - 0.5
    u0, v0 = np.floor(fu), np.floor(fv)
    wu, wv = fu - u0, fv - v0
    u0, v0 = u0.astype(np.int64) % U, v0.astype(np.int64) % V
    u1, v1 = (u0 + 1) % U, (v0 + 1) % V
    return ((v0, u0, (1 - wu) * (1 - wv)), (v0, u1, wu * (1 - wv)), (v1, u0, (1 - wu) * wv), (v1, u1, wu * wv))


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``image (V, U, C)`` at ``uv (..., 2)`` in [0, 1) (wraps): ``(..., C)``."""
    V, U = image.shape[:2]
    return sum(w[..., None] * image[v, u] for v, u, w in _bilinear_setup(uv, V, U))


def lookup(data: ShadingData, uv: np.ndarray, value: np.ndarray, above_max: str = "clamp") -> np.ndarray:
    """The operator S: shading-map value at ``uv (..., 2)`` for ``value (..., 3)`` (sr⁻¹), per channel."""
    if above_max not in ABOVE_MAX:
        raise ValueError(f"above_max is {above_max!r}; expected one of {list(ABOVE_MAX)}")
    value = np.nan_to_num(np.asarray(value, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    value = np.maximum(value, 0.0)
    x = value / data.a_max
    xc = np.minimum(x, 1.0)
    if data.compressed:
        k = bilinear(np.asarray(data.k_s, np.float64), uv)
        K = bilinear(np.asarray(data.exponent, np.float64), uv)
        with np.errstate(divide="ignore"):
            s = np.where(xc > 0, k * np.exp(K * np.log(np.where(xc > 0, xc, 1.0))), 0.0)
    else:
        S = data.slices
        assert S is not None, "ShadingData holds the full stack when it is not compressed"
        N, V, U, C = S.shape
        f = xc * (N - 1)
        l0 = np.minimum(np.floor(f).astype(np.int64), N - 2) if N > 1 else np.zeros(f.shape, np.int64)
        wl = f - l0
        l1 = np.minimum(l0 + 1, N - 1)
        c = np.broadcast_to(np.arange(C), f.shape)
        s = np.zeros(f.shape)
        for v, u, w in _bilinear_setup(uv, V, U):
            v, u, w = v[..., None], u[..., None], w[..., None]
            s += w * ((1 - wl) * S[l0, v, u, c] + wl * S[l1, v, u, c])
    if above_max == "scale":
        s = s * np.maximum(x, 1.0)
    return s


def _params(model, params: Mapping, T: int) -> dict[str, np.ndarray]:
    out = {}
    for p in model.parameters:
        if p.name not in params:
            raise ValueError(f"BRDF model {model.name!r}: parameter {p.name!r} missing; give all of "
                             f"{[q.name for q in model.parameters]}")
        v = np.asarray(params[p.name], np.float64).reshape(-1)
        if v.size not in (1, p.channels):
            raise ValueError(f"BRDF model {model.name!r}: parameter {p.name!r} needs {p.channels} value(s), got {v.size}")
        out[p.name] = np.broadcast_to(np.broadcast_to(v, (p.channels,)), (T, p.channels))
    return out


def r_value(model, params: Mapping, wi: np.ndarray, wo: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Eq 2: ``r = σ f_r(ω_o, ω_i) cos θ_i``, ``(..., 3)``; zero below either horizon."""
    wi, wo = np.broadcast_arrays(np.asarray(wi, np.float64), np.asarray(wo, np.float64))
    shape = wi.shape[:-1]
    T = int(np.prod(shape[:1])) if len(shape) > 1 else 1
    wi3 = wi.reshape(T, -1, 3)
    wo3 = wo.reshape(T, -1, 3)
    f = model.eval(_params(model, params, T), wi3, wo3)
    up = (wi3[..., 2] > 0) & (wo3[..., 2] > 0)
    r = np.where(up[..., None], sigma * f * np.clip(wi3[..., 2], 0.0, None)[..., None], 0.0)
    return np.nan_to_num(r, nan=0.0, posinf=0.0).reshape(shape + (3,))


def shade(data: ShadingData, model, params: Mapping, uv: np.ndarray, wi: np.ndarray, wo: np.ndarray,
          irradiance=1.0, *, sigma: float = 1.0, variant: str = "r", above_max: str = "clamp",
          texture_slice: int = -1) -> np.ndarray:
    """Radiance ``(..., 3)`` of a shading-mapped surface under one point or directional light.

    Parameters
    ----------
    data
        :class:`ShadingData` (full stack or compressed).
    model, params
        Any BRDF-model instance and its parameters as global values (``name -> (C,)`` or scalar).
    uv
        ``(..., 2)`` texture coordinates in [0, 1) (wrap around).
    wi, wo
        ``(..., 3)`` unit directions to the light and the viewer in the local frame (+z the normal).
    irradiance
        Light irradiance at normal incidence, scalar or ``(..., 3)`` (the paper's light intensity).
    sigma
        σ of Eq 2, the material's shade.
    variant
        One of :data:`VARIANTS` (Fig 6).
    above_max
        ``clamp`` or ``scale`` (§4) for lookups above a_max.
    texture_slice
        Slice used by the ``texture`` variant (default the brightest).
    """
    if variant not in VARIANTS:
        raise ValueError(f"variant is {variant!r}; expected one of {list(VARIANTS)}")
    uv, wi, wo = (np.asarray(a, np.float64) for a in (uv, wi, wo))
    batch = np.broadcast_shapes(uv.shape[:-1], wi.shape[:-1], wo.shape[:-1])
    wi, wo = np.broadcast_to(wi, batch + (3,)), np.broadcast_to(wo, batch + (3,))
    r = r_value(model, params, wi, wo, sigma)
    uv = np.broadcast_to(uv, batch + (2,))
    E = np.asarray(irradiance, np.float64)
    if variant == "r":
        return lookup(data, uv, r, above_max) * E
    if variant == "radiance":
        return lookup(data, uv, r * E, above_max)
    if variant == "texture":
        t = texture_slice % data.n_slices
        avg = data.a_max * t / (data.n_slices - 1)
        if avg <= 0:
            raise ValueError(f"texture_slice {texture_slice} is the black slice 0; choose a slice >= 1")
        tex = lookup(data, uv, np.full(r.shape, avg), "clamp") / avg
        return tex * r * E
    # angle: the acquired image nearest in elevation, as a texture of unit average
    table = angle_table(data)
    cos_i = np.clip(np.asarray(np.broadcast_to(wi, r.shape), np.float64)[..., 2], 0.0, 1.0)
    theta = np.degrees(np.arccos(cos_i))
    a = np.interp(theta, np.arange(ANGLE_TABLE_SIZE, dtype=np.float64), table)
    a = np.maximum(a, data.a_max / (data.n_slices - 1))[..., None]   # below slice 1 the map is linear in r
    tex = lookup(data, uv, np.broadcast_to(a, r.shape), "clamp") / a
    return tex * r * E


def latlong_directions(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre directions ``(H, W, 3)`` (+z up, row 0 at the zenith, φ from +x) and solid angles ``(H, W)``."""
    theta = (np.arange(height) + 0.5) / height * np.pi
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    return d, (np.pi / height) * (2 * np.pi / width) * np.sin(t)


def _pool(env: np.ndarray, height: int, width: int) -> np.ndarray:
    H, W = env.shape[:2]
    if H % height or W % width:
        raise ValueError(f"environment of {H}x{W} pixels cannot be pooled to {height}x{width}; use divisors")
    return env.reshape(height, H // height, width, W // width, -1).mean(axis=(1, 3))


def environment_samples(environment: np.ndarray, resolution=(16, 32)) -> tuple[np.ndarray, np.ndarray]:
    """Directional lights standing for a lat-long environment: ``(directions (D, 3), L_i dω (D, 3))``.

    The ``(H, W, 3)`` radiance image (local frame, row 0 at the zenith) is box-filtered to
    ``resolution`` and its upper-hemisphere pixels kept (D = rows/2 × columns for even rows).
    """
    env = np.asarray(environment, np.float64)
    if env.ndim != 3 or env.shape[-1] != 3 or not np.isfinite(env).all():
        raise ValueError(f"environment must be a finite (H, W, 3) lat-long image, got shape {env.shape}")
    env = _pool(env, *resolution)
    dirs, dw = latlong_directions(*resolution)
    up = dirs[..., 2] > 0
    return dirs[up], env[up] * dw[up][:, None]


def shade_environment(data: ShadingData, model, params: Mapping, uv: np.ndarray, wo: np.ndarray, environment: np.ndarray,
                      *, sigma: float = 1.0, variant: str = "r", above_max: str = "clamp", resolution=(16, 32),
                      texture_slice: int = -1, batch: int = 64) -> np.ndarray:
    """Eq 3 with a lat-long environment ``(H, W, 3)`` of radiance in the local frame: ``(..., 3)``.

    The environment is box-filtered to ``resolution`` (rows, columns) and each upper-hemisphere
    pixel becomes a directional light of irradiance ``L_i dω``.  For the ``radiance`` variant
    the lookup is outside the integral: ``S(∫ r L_i dω)``; the others integrate their
    point-light form.
    """
    dirs, Li = environment_samples(environment, resolution)
    wo = np.asarray(wo, np.float64)
    uv = np.broadcast_to(np.asarray(uv, np.float64), wo.shape[:-1] + (2,))
    flat_wo, flat_uv = wo.reshape(-1, 3), uv.reshape(-1, 2)
    out = np.zeros(flat_wo.shape)
    for b0 in range(0, len(dirs), batch):                        # batches of light directions, all pixels at once
        d, L = dirs[b0:b0 + batch], Li[b0:b0 + batch]
        wi = np.broadcast_to(d[None], (len(flat_wo),) + d.shape)
        wob = np.broadcast_to(flat_wo[:, None], wi.shape)
        uvb = np.broadcast_to(flat_uv[:, None], wi.shape[:-1] + (2,))
        if variant == "radiance":
            out += (r_value(model, params, wi, wob, sigma) * L[None]).sum(axis=1)
        else:
            out += shade(data, model, params, uvb, wi, wob, L[None], sigma=sigma, variant=variant, above_max=above_max,
                         texture_slice=texture_slice).sum(axis=1)
    if variant == "radiance":
        out = lookup(data, flat_uv, out, above_max)
    return out.reshape(wo.shape)
