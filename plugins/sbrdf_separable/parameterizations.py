"""Changes of variables for separable BRDFs (seed 001 §5.1) and the factor maps they are stored in (§5.3).

A parameterization splits a direction pair (ω_i, ω_o) into two 2D points x and
y, one per factor, as texture coordinates in [0, 1]²; the factors g_k(x),
h_k(y) are textures sampled bilinearly.  Four are provided, each a
``parameterization`` plugin:

================  ==========================  ==========================  ===============================
name              x (first factor)            y (second factor)           factor map
================  ==========================  ==========================  ===============================
standard          ω_i                         ω_o                         hemisphere map (xy | parabolic)
elevation-azimuth (θ_i, θ_o) / (π/2)          (φ_i, φ_o) / 2π (periodic)  angles
rusinkiewicz      h                           d in {u, v, h}, u from n    hemisphere map
gram-schmidt      h                           d in {t', s', h} (Eq 4, 6)  hemisphere map
================  ==========================  ==========================  ===============================

Hemisphere maps of a unit vector a with pole p and tangents (e1, e2)
(Eq 5): ``xy``: u = (a·e1 + 1)/2, v = (a·e2 + 1)/2; ``parabolic``:
u = (a·e1/(1 + a·p) + 1)/2, likewise v.

Eq 6 of the text writes h_v = (h·s' + 1)/2, which is 0.5 everywhere (s' is
perpendicular to h by construction); the XY hemisphere map of h meant there
is h_v = (h·s + 1)/2 with the surface's secondary tangent s, as used here.

The Rusinkiewicz frame takes u from the normal, −norm(n − (n·h) h), which is
undefined at h = n: tiny changes of the directions near the specular
configuration swing the difference vector's azimuth around (the instability
§5.1 reports; ``tests/plugins/test_separable_parameterizations.py`` measures
it).  Exactly at h = n it falls back to u = t, the limit along φ_h = 0.
Gram–Schmidt takes t' from the tangent instead, undefined only at h = ±t,
which needs a grazing retro-reflection (there it falls back to t' = −n).
"""

from __future__ import annotations

import numpy as np

from .declarations import PARAMETERIZATION

#: Largest radius of a hemisphere-map point the inverse maps back (texture corners lie outside the disc):
#: points beyond it are pulled onto this circle, i.e. onto directions just above the horizon.
RIM = 1.0 - 1e-6
EPS = 1e-12


def _dot(a, b):
    return np.einsum("...k,...k->...", a, b)


def _norm(a, fallback):
    n = np.sqrt(_dot(a, a))[..., None]
    return np.where(n > 1e-9, a / np.where(n > 1e-9, n, 1.0), fallback)


# -- hemisphere maps --------------------------------------------------------------------------------------


def map_forward(kind: str, a: np.ndarray) -> np.ndarray:
    """Local unit vector ``(..., 3)`` (pole = +z) -> texture coordinates ``(..., 2)``."""
    if kind == "xy":
        return (a[..., :2] + 1.0) * 0.5
    return (a[..., :2] / (1.0 + np.maximum(a[..., 2:3], -1.0 + 1e-6)) + 1.0) * 0.5


def map_inverse(kind: str, uv: np.ndarray) -> np.ndarray:
    """Texture coordinates -> local unit vector with z ≥ 0; points outside the disc go to its rim."""
    p = 2.0 * np.asarray(uv, float) - 1.0
    r = np.sqrt(_dot(p, p))
    p = p * (np.minimum(r, RIM) / np.maximum(r, EPS))[..., None]
    r2 = _dot(p, p)
    if kind == "xy":
        return np.concatenate([p, np.sqrt(np.maximum(1.0 - r2, 0.0))[..., None]], axis=-1)
    z = (1.0 - r2) / (1.0 + r2)
    return np.concatenate([p * (1.0 + z)[..., None], z[..., None]], axis=-1)


def _glsl_map(kind: str) -> str:
    if kind == "xy":
        return "vec2 sep_map(vec3 a) { return (a.xy + 1.0) * 0.5; }\n"
    return "vec2 sep_map(vec3 a) { return (a.xy / (1.0 + max(a.z, -1.0 + 1e-6)) + 1.0) * 0.5; }\n"


# -- the parameterizations ----------------------------------------------------------------------------------


class Parameterization:
    """Base: ``coords`` / ``directions`` / ``wrap`` / ``glsl`` (see the hook ``sbrdf_parameterizations``)."""

    name = ""
    #: Per factor (x, y), per texture axis (u, v): periodic?
    wrap = ((False, False), (False, False))

    params = PARAMETERIZATION

    def __init__(self, *, map: str = "xy"):  # noqa: A002 - the declared parameter's name
        if map not in ("xy", "parabolic"):
            raise ValueError(f"parameterization {self.name!r}: map must be 'xy' or 'parabolic', got {map!r}")
        self.map = map

    def config(self) -> dict:
        return {"map": self.map}

    def coords(self, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def directions(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def glsl(self) -> str:
        raise NotImplementedError


class Standard(Parameterization):
    """Incident/view, (θ_i, φ_i) × (θ_o, φ_o): best for "deep microgeometry" (velvet, §5.2)."""

    name = "standard"

    def coords(self, wi, wo):
        return map_forward(self.map, wi), map_forward(self.map, wo)

    def directions(self, x, y):
        wi, wo = map_inverse(self.map, x), map_inverse(self.map, y)
        return np.broadcast_arrays(wi, wo)

    def glsl(self):
        return _glsl_map(self.map) + (
            "void sep_coords(vec3 wi, vec3 wo, out vec2 x, out vec2 y) { x = sep_map(wi); y = sep_map(wo); }\n")


class ElevationAzimuth(Parameterization):
    """(θ_i, θ_o) × (φ_i, φ_o): angles straight onto the texture, φ periodic (software rendering only, §5.3)."""

    name = "elevation-azimuth"
    wrap = ((False, False), (True, True))

    def __init__(self, *, map: str = "xy"):  # noqa: A002 - accepted for a uniform signature; angles need no map
        super().__init__(map=map)

    def config(self):
        return {}

    def coords(self, wi, wo):
        def theta(a):
            return np.arccos(np.clip(a[..., 2], -1.0, 1.0)) / (0.5 * np.pi)

        def phi(a):
            return np.mod(np.arctan2(a[..., 1], a[..., 0]) / (2 * np.pi), 1.0)

        return np.stack([theta(wi), theta(wo)], -1), np.stack([phi(wi), phi(wo)], -1)

    def directions(self, x, y):
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        t = np.clip(x, 0.0, 1.0) * 0.5 * np.pi
        p = y * 2 * np.pi

        def sph(t, p):
            return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)

        return sph(t[..., 0], p[..., 0]), sph(t[..., 1], p[..., 1])

    def glsl(self):
        return (
            "void sep_coords(vec3 wi, vec3 wo, out vec2 x, out vec2 y) {\n"
            "    x = acos(clamp(vec2(wi.z, wo.z), -1.0, 1.0)) / 1.5707963268;\n"
            "    y = fract(vec2(atan(wi.y, wi.x), atan(wo.y, wo.x)) / 6.2831853072 + 1.0);\n"
            "}\n")


class _HalfDifference(Parameterization):
    """x = h in the surface frame; y = ω_i in a frame {e1, e2, h} built from h."""

    def frame(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def coords(self, wi, wo):
        h = _norm(wi + wo, np.array([0.0, 0.0, 1.0]))
        e1, e2 = self.frame(h)
        d = np.stack([_dot(wi, e1), _dot(wi, e2), _dot(wi, h)], -1)
        return map_forward(self.map, h), map_forward(self.map, d)

    def directions(self, x, y):
        h, d = map_inverse(self.map, x), map_inverse(self.map, y)
        e1, e2 = self.frame(h)
        wi = d[..., :1] * e1 + d[..., 1:2] * e2 + d[..., 2:3] * h
        wo = 2.0 * _dot(wi, h)[..., None] * h - wi
        return wi, wo


class Rusinkiewicz(_HalfDifference):
    """Halfway/difference (Rusinkiewicz 1998): u = −norm(n − (n·h) h), v = h × u; unstable at h ≈ n."""

    name = "rusinkiewicz"

    def frame(self, h):
        n = np.array([0.0, 0.0, 1.0])
        u = -_norm(n - h[..., 2:3] * h, -np.array([1.0, 0.0, 0.0]))
        return u, np.cross(h, u)

    def glsl(self):
        return _glsl_map(self.map) + (
            "void sep_coords(vec3 wi, vec3 wo, out vec2 x, out vec2 y) {\n"
            "    vec3 h = wi + wo; float lh = length(h); h = lh > 1e-9 ? h / lh : vec3(0.0, 0.0, 1.0);\n"
            "    vec3 u = vec3(0.0, 0.0, 1.0) - h.z * h; float lu = length(u);\n"
            "    u = lu > 1e-9 ? -u / lu : vec3(1.0, 0.0, 0.0);\n"
            "    vec3 v = cross(h, u);\n"
            "    x = sep_map(h); y = sep_map(vec3(dot(wi, u), dot(wi, v), dot(wi, h)));\n"
            "}\n")


class GramSchmidt(_HalfDifference):
    """Gram–Schmidt halfvector (Eq 4, 6): t' = norm(t − (t·h) h), s' = h × t'; stable wherever h ≠ ±t."""

    name = "gram-schmidt"

    def frame(self, h):
        t = np.array([1.0, 0.0, 0.0])
        tp = _norm(t - h[..., :1] * h, -np.array([0.0, 0.0, 1.0]))
        return tp, np.cross(h, tp)

    def glsl(self):
        return _glsl_map(self.map) + (
            "void sep_coords(vec3 wi, vec3 wo, out vec2 x, out vec2 y) {\n"
            "    vec3 h = wi + wo; float lh = length(h); h = lh > 1e-9 ? h / lh : vec3(0.0, 0.0, 1.0);\n"
            "    vec3 tp = vec3(1.0, 0.0, 0.0) - h.x * h; float lt = length(tp);\n"
            "    tp = lt > 1e-9 ? tp / lt : vec3(0.0, 0.0, -1.0);\n"
            "    vec3 sp = cross(h, tp);\n"
            "    x = sep_map(h); y = sep_map(vec3(dot(wi, tp), dot(wi, sp), dot(wi, h)));\n"
            "}\n")
