"""Mesostructure for simulated cameras: a height field (mm) with per-texel albedo.

Kautz et al. 2003 (seed 002) photograph materials whose look comes from fine
surface structure: bumps that tilt the local normal, cast shadows on their
neighbours and hide parts of each other from the camera.  This module lets the
virtual camera photograph such a material so shading-map tests have a known
truth.  The sample's flat plane z = 0 becomes the surface ``z = h(x, y)``
sampled on the material's texel grid (``height[v, u]``, v along +y, u along +x,
the same grid as the parameter maps); each facet reflects with

    f_r = albedo(x) / π                               (``facet: lambert``)
    f_r = albedo(x) · model(ω_i', ω_o')               (``facet: model``)

where ω' are the directions in the facet's own frame (its normal from the
height gradient).  The two non-local effects cost a ray march each and are
computed only when the camera's ``effects`` list them:

* ``shadowing``: a point whose ray to the light passes below the height field
  gets no direct light;
* ``masking``: each pixel's ray stops at its first intersection with the height
  field (parallax and occlusion) instead of at the plane z = 0.

Configuration (the camera's ``mesostructure`` parameter)::

    mesostructure:
      height_mm: {procedural: bumps, amplitude_mm: 0.5, period_mm: 4.0, seed: 1}   # or a .npy path, or a number
      albedo: [0.7, 0.6, 0.5]        # or a number, a .npy path (V, U[, 3]), or {procedural: noise, low:, high:, seed:}
      facet: lambert                 # or model: the camera's BRDF model (and its maps) on each facet

Numpy arrays are accepted in place of paths when the camera is built from Python.
Shared by the ``virtual-camera`` device (``sbrdf_devices``) and the shading
plugins' simulated captures.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sbrdf_core.errors import ParameterError

__all__ = ["KEYS", "MAX_STEPS", "PROCEDURAL", "Mesostructure", "normals", "procedural"]

KEYS = ("height_mm", "albedo", "facet")
PROCEDURAL = ("bumps", "ridges", "noise")
#: Most march steps per ray (bounds the cost at grazing angles).
MAX_STEPS = 768


def _load(value, where: str) -> np.ndarray:
    if isinstance(value, (str, Path)):
        path = Path(value)
        if path.suffix != ".npy":
            raise ParameterError(f"virtual-camera: mesostructure.{where}: {path} is not a .npy file")
        try:
            return np.load(path)
        except OSError as e:
            raise ParameterError(f"virtual-camera: mesostructure.{where}: cannot read {path}: {e}") from None
    return np.asarray(value, np.float64)


def procedural(spec: Mapping, texels: tuple[int, int], size_mm: tuple[float, float], where: str) -> np.ndarray:
    """A ``(V, U)`` procedural field: ``bumps`` (random smooth dimples), ``ridges`` (weave-like), ``noise``.

    ``amplitude_mm``/``period_mm`` for heights; ``low``/``high`` for albedo-style ranges (then the
    field spans [low, high]); ``seed`` fixes the randomness.
    """
    allowed = {"procedural", "amplitude_mm", "period_mm", "seed", "low", "high"}
    unknown = sorted(set(spec) - allowed)
    if unknown:
        raise ParameterError(f"virtual-camera: mesostructure.{where}: unknown key(s) {unknown}; accepted: {sorted(allowed)}")
    kind = spec.get("procedural")
    if kind not in PROCEDURAL:
        raise ParameterError(f"virtual-camera: mesostructure.{where}.procedural is {kind!r}; expected one of {list(PROCEDURAL)}")
    U, V = texels
    sx, sy = size_mm
    x = (np.arange(U) + 0.5) / U * sx
    y = (np.arange(V) + 0.5) / V * sy
    xx, yy = np.meshgrid(x, y)
    period = float(spec.get("period_mm", min(sx, sy) / 8))
    rng = np.random.default_rng(int(spec.get("seed", 0)))
    if kind == "ridges":
        shift = np.pi / 2 * (np.floor(xx / period) % 2)  # alternate columns offset: a weave
        f = 0.5 + 0.25 * (np.sin(2 * np.pi * xx / period) + np.sin(2 * np.pi * yy / period + shift))
    else:
        # A sum of random sinusoids at about the period (bumps) or over an octave range (noise).
        waves = 12
        scale = rng.uniform(0.8, 1.25, waves) if kind == "bumps" else 2.0 ** rng.uniform(-1.0, 1.5, waves)
        angle = rng.uniform(0, np.pi, waves)
        phase = rng.uniform(0, 2 * np.pi, waves)
        f = sum(np.cos(2 * np.pi * (np.cos(a) * xx + np.sin(a) * yy) / (period / s) + p)
                for s, a, p in zip(scale, angle, phase))
        f = (f - f.min()) / max(f.max() - f.min(), 1e-12)
        if kind == "bumps":
            f = f**2  # round tops, narrow valleys
    if "amplitude_mm" in spec:
        return float(spec["amplitude_mm"]) * f
    lo, hi = float(spec.get("low", 0.0)), float(spec.get("high", 1.0))
    return lo + (hi - lo) * f


def normals(height: np.ndarray, du_mm: float, dv_mm: float) -> np.ndarray:
    """Unit normals ``(V, U, 3)`` of ``z = h`` from central differences (one-sided at the edges)."""
    gy, gx = np.gradient(height, dv_mm, du_mm) if min(height.shape) > 1 else (np.zeros_like(height),) * 2
    n = np.stack([-gx, -gy, np.ones_like(height)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


class Mesostructure:
    """A height field with per-texel albedo over the sample ``size_mm`` (centred at the origin)."""

    def __init__(self, height_mm: np.ndarray, albedo: np.ndarray, size_mm: tuple[float, float], facet: str = "lambert"):
        self.height = np.asarray(height_mm, np.float64)
        V, U = self.height.shape
        a = np.asarray(albedo, np.float64)
        self.albedo = np.broadcast_to(a if a.ndim == 3 else (a[..., None] if a.ndim == 2 else a), (V, U, 3)).copy()
        self.size_mm = (float(size_mm[0]), float(size_mm[1]))
        self.facet = facet
        self.du, self.dv = self.size_mm[0] / U, self.size_mm[1] / V
        self.normal = normals(self.height, self.du, self.dv)
        # The carrier around the sample is the plane z = 0: marches must cover it too.
        self.h_min, self.h_max = min(float(self.height.min()), 0.0), max(float(self.height.max()), 0.0)

    @classmethod
    def from_config(cls, config: Mapping, texels: tuple[int, int], size_mm) -> Mesostructure:
        """Build from the camera's ``mesostructure`` parameter (see the module docstring)."""
        if not isinstance(config, Mapping):
            raise ParameterError(f"virtual-camera: mesostructure must be a mapping with keys {list(KEYS)}, got {config!r}")
        unknown = sorted(set(config) - set(KEYS))
        if unknown:
            raise ParameterError(f"virtual-camera: mesostructure: unknown key(s) {unknown}; accepted: {list(KEYS)}")
        U, V = texels
        fields = {}
        for key, default in (("height_mm", 0.0), ("albedo", 0.8)):
            value = config.get(key, default)
            fields[key] = procedural(value, texels, size_mm, key) if isinstance(value, Mapping) else _load(value, key)
        h = fields["height_mm"]
        h = np.broadcast_to(h, (V, U)) if h.ndim == 0 else h
        if h.ndim != 2 or not np.isfinite(h).all():
            raise ParameterError(f"virtual-camera: mesostructure.height_mm: expected a finite (V, U) array, got shape {h.shape}")
        a = fields["albedo"]
        try:
            a = np.broadcast_to(a if a.ndim != 2 else a[..., None], h.shape + (3,))
        except ValueError:
            raise ParameterError(f"virtual-camera: mesostructure.albedo: shape {a.shape} does not fit the height "
                                 f"field {h.shape} (a number, [r, g, b], (V, U) or (V, U, 3))") from None
        if not (np.isfinite(a).all() and (a >= 0).all()):
            raise ParameterError("virtual-camera: mesostructure.albedo: values must be finite and non-negative")
        facet = config.get("facet", "lambert")
        if facet not in ("lambert", "model"):
            raise ParameterError(f"virtual-camera: mesostructure.facet is {facet!r}; expected 'lambert' or 'model'")
        return cls(h, a, size_mm, facet)

    @property
    def texels(self) -> tuple[int, int]:
        return self.height.shape[1], self.height.shape[0]

    # -- lookups --------------------------------------------------------------------------------

    def texel_index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest texel ``(v, u)`` of sample-frame points (clamped to the grid)."""
        U, V = self.texels
        u = np.clip(((x + self.size_mm[0] / 2) / self.du).astype(np.int64), 0, U - 1)
        v = np.clip(((y + self.size_mm[1] / 2) / self.dv).astype(np.int64), 0, V - 1)
        return v, u

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear height at sample-frame points; 0 (the carrier) outside the sample."""
        U, V = self.texels
        fu = np.clip((x + self.size_mm[0] / 2) / self.du - 0.5, 0, U - 1)
        fv = np.clip((y + self.size_mm[1] / 2) / self.dv - 0.5, 0, V - 1)
        u0, v0 = np.minimum(fu.astype(np.int64), max(U - 2, 0)), np.minimum(fv.astype(np.int64), max(V - 2, 0))
        u1, v1 = np.minimum(u0 + 1, U - 1), np.minimum(v0 + 1, V - 1)
        a, b = fu - u0, fv - v0
        h = self.height
        z = (h[v0, u0] * (1 - a) + h[v0, u1] * a) * (1 - b) + (h[v1, u0] * (1 - a) + h[v1, u1] * a) * b
        inside = (np.abs(x) < self.size_mm[0] / 2) & (np.abs(y) < self.size_mm[1] / 2)
        return np.where(inside, z, 0.0)

    def _steps(self, horizontal_mm: float) -> int:
        return int(np.clip(np.ceil(horizontal_mm / (0.5 * min(self.du, self.dv))), 1, MAX_STEPS))

    # -- the two ray marches ------------------------------------------------------------------------

    def shadowed(self, points: np.ndarray, light_pos: np.ndarray) -> np.ndarray:
        """``(n,)`` bool: the segment from each surface point towards the light passes below the surface.

        Marched until the ray rises above the highest point (half a texel per step, at most
        :data:`MAX_STEPS`); the first sample sits one step away so a facet does not shadow itself.
        """
        d = light_pos - points
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        up = d[:, 2] > 1e-9
        out = ~up
        if not up.any() or self.h_max - self.h_min <= 0:
            return out
        p, d = points[up], d[up]
        t_end = (self.h_max - p[:, 2]) / d[:, 2]
        K = self._steps(float((t_end * np.linalg.norm(d[:, :2], axis=-1)).max()))
        eps = 1e-4 * (self.h_max - self.h_min)
        blocked = np.zeros(len(p), bool)
        for k in range(1, K + 1):
            q = p + (t_end * k / K)[:, None] * d
            blocked |= self.height_at(q[:, 0], q[:, 1]) > q[:, 2] + eps
        out[up] = blocked
        return out

    def first_hit(self, origin: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First intersection of rays with the surface: ``(points (n, 3), hit (n,) bool)``.

        Marches between the planes z = h_max and z = h_min and refines the bracketing step
        by the secant; rays that never go down, or miss, get ``hit = False``.
        """
        n = len(origin)
        pts = np.zeros((n, 3))
        down = direction[:, 2] < -1e-12
        hit = np.zeros(n, bool)
        if not down.any():
            return pts, hit
        o, d = origin[down], direction[down]
        t0 = (self.h_max - o[:, 2]) / d[:, 2]
        t1 = (self.h_min - o[:, 2]) / d[:, 2]
        K = self._steps(float(((t1 - t0) * np.linalg.norm(d[:, :2], axis=-1)).max())) + 1
        t_prev, f_prev = t0, np.full(len(o), np.inf)
        t_hit, found = t1.copy(), np.zeros(len(o), bool)
        for k in range(K + 1):
            t = t0 + (t1 - t0) * k / K
            q = o + t[:, None] * d
            f = q[:, 2] - self.height_at(q[:, 0], q[:, 1])
            new = ~found & (f <= 0)
            if new.any():
                fp = np.where(np.isfinite(f_prev), f_prev, 0.0)
                denom = np.where(fp - f > 0, fp - f, 1.0)
                t_hit[new] = np.where(np.isfinite(f_prev), t_prev + (t - t_prev) * fp / denom, t)[new]
                found |= new
            t_prev, f_prev = t, f
            if found.all():
                break
        pts[down] = o + t_hit[:, None] * d
        hit[down] = True
        return pts, hit

    # -- shading ------------------------------------------------------------------------------------

    def facet_frame(self, v: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-point facet frame ``(t, b, n)``: n the normal, t the sample's +x projected onto the facet."""
        n = self.normal[v, u]
        t = np.array([1.0, 0.0, 0.0]) - n[:, :1] * n
        t /= np.linalg.norm(t, axis=-1, keepdims=True)
        return t, np.cross(n, t), n

    def to_local(self, w: np.ndarray, frame) -> np.ndarray:
        t, b, n = frame
        return np.stack([(w * t).sum(-1), (w * b).sum(-1), (w * n).sum(-1)], axis=-1)
