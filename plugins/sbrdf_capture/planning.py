"""Acquisition planning: how densely to sample, where to put the camera, which poses, which exposures.

Everything here reproduces seed 000 chapter 3 (notes §3.3–3.7):

* :func:`sampling_density` — Eq 3.1–3.6: from the sharpest highlight (Phong
  exponent ``n``, the falloff threshold that bounds it, ``p`` samples wanted
  inside it) to the highlight half-width θ_r, its share ``g`` of the
  hemisphere, the number ``m`` of uniform samples and the spacing θ_d in the
  2D, 3D (isotropic) and 4D (anisotropic) domains.  Also the motor-tolerance
  analysis of §3.3.1 (:func:`exponent_for_falloff`, :func:`angular_error_budget_deg`).
* :func:`camera_geometry` — Eq 3.7–3.8 and Table 3.3: fields of view, and
  range / sample side / pixels per mm with one of them fixed.
* :func:`choose_poses` / :func:`plan_poses` — the greedy pose chooser:
  candidates in scan order, each accepted unless its direction pair lies
  within θ_d of an accepted one under the bi-angular distance, with
  reciprocal pairs equal and, for isotropic samples, pairs equal under a
  rotation about the normal and a mirror across the plane of incidence;
  θ_i ≤ 75°, θ_r ≤ 65°.
* :func:`plan_exposures` — 1–3 shutter times per pose predicted from the
  angle between the view direction and the mirror direction (§3.4.1).

The thesis leaves the distance formula open (notes §18.2).  This module uses
``d = sqrt(∠(ω_i, ω_i')² + ∠(ω_r, ω_r')²)``; for isotropic samples the
rotation about the normal that minimises ``d`` is found per pair (exactly at
the poles, where the azimuth is meaningless: that is the bug behind the
footnote of Table 3.2, which oversampled the poles).

The greedy chooser is batched: accepting a pose marks every candidate within
θ_d of it as covered in one vectorised pass over a pre-selected neighbourhood
(dot-product bounds on ω_i and ω_r for anisotropic samples; polar-angle bounds for
isotropic ones), and the next pose is found by ``argmax``, never by a Python
loop over candidate pairs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sbrdf_lib.rig_geometry import RigGeometry, forward, inverse

# =====================================================================================================
# Sampling density (Eq 3.1-3.6) and motor tolerance (§3.3.1)
# =====================================================================================================


def phong_falloff(theta_deg, exponent):
    """Eq 3.1: ``f_n(θ) = cos^n θ``, the falloff θ away from a highlight's peak."""
    return np.cos(np.deg2rad(theta_deg)) ** exponent


def exponent_for_falloff(falloff: float, angle_deg: float) -> float:
    """The Phong exponent whose highlight falls to ``falloff`` at ``angle_deg`` (0.75 at 1° → 1888.7)."""
    return math.log(falloff) / math.log(math.cos(math.radians(angle_deg)))


def angular_error_budget_deg(pan_deg: float = 0.786, tilt_deg: float = 0.786, light_deg: float = 0.1411) -> float:
    """§3.3.1: pan and tilt repeatabilities add (roll is perpendicular), plus the light's: 1.713°."""
    return pan_deg + tilt_deg + light_deg


@dataclass(frozen=True)
class SamplingDensity:
    """Result of :func:`sampling_density`; angles in degrees."""

    exponent: float
    threshold: float
    samples_per_highlight: int
    theta_r_deg: float      # highlight half-width: f(θ_r) = threshold
    g: float                # Eq 3.2: highlight share of the hemisphere, 1 - cos θ_r
    m: int                  # Eq 3.3: uniform samples for p inside the highlight, ceil(p / g)
    theta_d2_deg: float     # Eq 3.4
    theta_d3_deg: float     # Eq 3.5 (isotropic BRDF domain)
    theta_d4_deg: float     # Eq 3.6 (anisotropic BRDF domain)


def sampling_density(exponent: float = 128.0, threshold: float = 0.3, samples_per_highlight: int = 4) -> SamplingDensity:
    """Eq 3.1–3.6 for a highlight ``cos^n`` that must be caught by ``p`` samples above ``threshold``.

    The thesis' example (n = 128, f = 0.3, p = 4): θ_r = 7.84°, g = 0.00934,
    m = 428, θ_d = 6.94° / 16.3° / 31.6° in 2D / 3D / 4D.
    """
    if not (0.0 < threshold < 1.0):
        raise ValueError(f"threshold must be in (0, 1), got {threshold}")
    if exponent <= 0 or samples_per_highlight < 1:
        raise ValueError(f"need exponent > 0 and samples_per_highlight >= 1, got {exponent}, {samples_per_highlight}")
    theta_r = math.acos(threshold ** (1.0 / exponent))
    g = 1.0 - math.cos(theta_r)
    zeta = 2.0 * math.pi * g                      # highlight solid angle, sr
    p = samples_per_highlight
    return SamplingDensity(
        exponent=float(exponent), threshold=float(threshold), samples_per_highlight=int(p),
        theta_r_deg=math.degrees(theta_r), g=g, m=math.ceil(p / g - 1e-9),
        theta_d2_deg=math.degrees(math.sqrt(zeta / p)),
        theta_d3_deg=math.degrees((math.pi / 2.0 * zeta / p) ** (1.0 / 3.0)),
        theta_d4_deg=math.degrees((2.0 * math.pi * zeta / p) ** 0.25),
    )


# =====================================================================================================
# Camera geometry (Eq 3.7-3.8, Table 3.3)
# =====================================================================================================


@dataclass(frozen=True)
class CameraGeometry:
    """Result of :func:`camera_geometry`: one column of Table 3.3."""

    focal_px: float
    res_h: int
    res_v: int
    fov_h_deg: float
    fov_v_deg: float
    range_mm: float
    side_mm: float
    pixels_per_mm: float

    @property
    def fov_h_rad(self) -> float:
        return math.radians(self.fov_h_deg)

    @property
    def fov_v_rad(self) -> float:
        return math.radians(self.fov_v_deg)

    @property
    def mm_per_pixel(self) -> float:
        return 1.0 / self.pixels_per_mm


def camera_geometry(focal_px: float, res_h: int, res_v: int, *, side_mm: float | None = None,
                    range_mm: float | None = None, pixels_per_mm: float | None = None) -> CameraGeometry:
    """Fields of view and the (range, side, pixels/mm) triple with exactly one of them fixed.

    ``fov = 2 atan(res / 2 f)``; Eq 3.7 ``l = 2 r tan(fov_v / 2)``; Eq 3.8
    ``p = res_v / l`` (the vertical field is the smaller one, so it bounds
    the sample side).  Kodak DCS 520 with the 50 mm lens (f = 4165 px,
    1728 × 1152) and l = 300 mm: r = 1084.6 mm (Table 3.3 truncates to 1084).
    """
    given = [v is not None for v in (side_mm, range_mm, pixels_per_mm)]
    if sum(given) != 1:
        raise ValueError("give exactly one of side_mm, range_mm, pixels_per_mm")
    fov_h = 2.0 * math.atan(res_h / (2.0 * focal_px))
    fov_v = 2.0 * math.atan(res_v / (2.0 * focal_px))
    tan_half = math.tan(fov_v / 2.0)
    if pixels_per_mm is not None:
        side_mm = res_v / pixels_per_mm
    if side_mm is not None:
        range_mm = side_mm / (2.0 * tan_half)
    else:
        assert range_mm is not None, "exactly one of the three is given"
        side_mm = 2.0 * range_mm * tan_half
    return CameraGeometry(float(focal_px), int(res_h), int(res_v), math.degrees(fov_h), math.degrees(fov_v),
                          float(range_mm), float(side_mm), res_v / side_mm)


# =====================================================================================================
# Bi-angular distance with reciprocity and isotropic symmetry
# =====================================================================================================


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


def _polar(theta_a, phi_a, theta_b, phi_b):
    """Great-circle angle between directions given by polar angle and azimuth (radians)."""
    c = np.cos(theta_a) * np.cos(theta_b) + np.sin(theta_a) * np.sin(theta_b) * np.cos(phi_a - phi_b)
    return np.arccos(np.clip(c, -1.0, 1.0))


def canonical_isotropic(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``(..., 3)`` coordinates (θ_i, θ_r, |φ_r − φ_i| in [0, π]) of direction pairs, radians."""
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    ti = np.arccos(np.clip(wi[..., 2], -1, 1))
    tr = np.arccos(np.clip(wo[..., 2], -1, 1))
    dphi = np.arctan2(wo[..., 1], wo[..., 0]) - np.arctan2(wi[..., 1], wi[..., 0])
    return np.stack([ti, tr, np.abs((dphi + np.pi) % (2 * np.pi) - np.pi)], axis=-1)


def _isotropic_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance between canonical pairs ``a (3,)`` and ``b (N, 3)``, minimised over a rotation about the normal.

    For each mirror choice the rotation ψ applied to ``b`` enters as
    ``∠(ω_i, ω_i')(ψ)`` and ``∠(ω_r, ω_r')(Δ − ψ)``; the minimiser of the
    small-angle expansion, ``ψ* = w_r Δ / (w_i + w_r)`` with
    ``w = sin θ sin θ'``, is tried with ψ = 0 and ψ = Δ, and the least kept.
    At a pole (``w_i = 0``) ψ* = Δ aligns the azimuths exactly.
    """
    ti, tr, p = a
    tib, trb, pb = b[:, 0], b[:, 1], b[:, 2]
    wi_w = np.sin(ti) * np.sin(tib)
    wr_w = np.sin(tr) * np.sin(trb)
    best = np.full(len(b), np.inf)
    for delta in (p - pb, p + pb):
        delta = (delta + np.pi) % (2 * np.pi) - np.pi
        star = wr_w * delta / np.maximum(wi_w + wr_w, 1e-12)
        for psi in (np.zeros_like(delta), delta, star):
            d2 = _polar(ti, 0.0, tib, psi) ** 2 + _polar(tr, 0.0, trb, delta - psi) ** 2
            best = np.minimum(best, d2)
    return np.sqrt(best)


def bi_angular_distance(wi_a, wo_a, wi_b, wo_b, *, isotropic: bool, reciprocal: bool = True) -> np.ndarray:
    """Degrees between direction pair ``a`` (one pair) and pairs ``b`` (``(N, 3)`` each).

    ``sqrt(∠(ω_i, ω_i')² + ∠(ω_r, ω_r')²)``, minimised over the equivalent
    forms of ``b``: its reciprocal (ω_i ↔ ω_r) and, for isotropic samples,
    its rotations about the normal and its mirror image.
    """
    wi_b, wo_b = np.atleast_2d(wi_b), np.atleast_2d(wo_b)
    if isotropic:
        a = canonical_isotropic(wi_a, wo_a)
        b = canonical_isotropic(wi_b, wo_b)
        d = _isotropic_distance(a, b)
        if reciprocal:
            d = np.minimum(d, _isotropic_distance(a, b[:, [1, 0, 2]]))
    else:
        wi_a, wo_a = np.asarray(wi_a, float), np.asarray(wo_a, float)
        d = np.hypot(_angle(wi_a, wi_b), _angle(wo_a, wo_b))
        if reciprocal:
            d = np.minimum(d, np.hypot(_angle(wi_a, wo_b), _angle(wo_a, wi_b)))
    return np.rad2deg(d)


# =====================================================================================================
# Greedy pose chooser
# =====================================================================================================


def choose_poses(wi, wo, theta_d_deg: float, *, isotropic: bool, max_theta_i_deg: float = 75.0,
                 max_theta_r_deg: float = 65.0, reciprocal: bool = True) -> np.ndarray:
    """Indices of the candidates the greedy chooser keeps, in candidate order.

    Walks the candidates in the order given and keeps one whenever no kept
    pair is within ``theta_d_deg`` of it (:func:`bi_angular_distance`);
    candidates beyond the polar limits are never kept.
    """
    wi = np.asarray(wi, dtype=float).reshape(-1, 3)
    wo = np.asarray(wo, dtype=float).reshape(-1, 3)
    theta_i = np.arccos(np.clip(wi[:, 2], -1, 1))
    theta_r = np.arccos(np.clip(wo[:, 2], -1, 1))
    covered = (theta_i > math.radians(max_theta_i_deg)) | (theta_r > math.radians(max_theta_r_deg))
    covered |= ~np.isfinite(wi).all(axis=1) | ~np.isfinite(wo).all(axis=1)
    radius = math.radians(theta_d_deg)
    neighbours = _neighbour_finder(wi, wo, theta_i, theta_r, radius, isotropic=isotropic, reciprocal=reciprocal)
    chosen: list[int] = []
    start = 0
    n = len(wi)
    while start < n:
        open_ = ~covered[start:]
        if not open_.any():
            break
        k = start + int(np.argmax(open_))
        chosen.append(k)
        covered[k] = True
        idx = neighbours(k)
        idx = idx[~covered[idx]]
        if len(idx):
            d = bi_angular_distance(wi[k], wo[k], wi[idx], wo[idx], isotropic=isotropic, reciprocal=reciprocal)
            covered[idx[d < theta_d_deg]] = True
        start = k + 1
    return np.asarray(chosen, dtype=int)


def _neighbour_finder(wi, wo, theta_i, theta_r, radius, *, isotropic: bool, reciprocal: bool):
    """``k -> indices > k`` of candidates that may lie within ``radius`` of candidate ``k`` (a superset).

    Only later candidates matter to a first-come chooser.  Anisotropic: both
    angles of a close pair are below ``radius``, i.e. both dot products exceed
    ``cos(radius)``.  Isotropic (rotations about the normal allowed): polar
    angles still bound the distance, ``|Δθ_i|, |Δθ_r| < radius``.
    """
    cos_r = math.cos(min(radius, math.pi))
    WI, WO = np.ascontiguousarray(wi.T), np.ascontiguousarray(wo.T)

    def dot(columns: np.ndarray, k0: int, v: np.ndarray) -> np.ndarray:
        return columns[0, k0:] * v[0] + columns[1, k0:] * v[1] + columns[2, k0:] * v[2]

    def anisotropic(k: int) -> np.ndarray:
        k0 = k + 1
        near = (dot(WI, k0, wi[k]) > cos_r) & (dot(WO, k0, wo[k]) > cos_r)
        if reciprocal:
            near |= (dot(WI, k0, wo[k]) > cos_r) & (dot(WO, k0, wi[k]) > cos_r)
        return k0 + np.flatnonzero(near)

    def isotropic_(k: int) -> np.ndarray:
        k0 = k + 1
        ti, tr = theta_i[k0:], theta_r[k0:]
        near = (np.abs(ti - theta_i[k]) < radius) & (np.abs(tr - theta_r[k]) < radius)
        if reciprocal:
            near |= (np.abs(ti - theta_r[k]) < radius) & (np.abs(tr - theta_i[k]) < radius)
        return k0 + np.flatnonzero(near)

    return isotropic_ if isotropic else anisotropic


def direction_candidates(step_deg: float, *, isotropic: bool, max_theta_i_deg: float = 75.0,
                         max_theta_r_deg: float = 65.0) -> tuple[np.ndarray, np.ndarray]:
    """Quasi-uniform candidate pairs ``(wi, wo)`` about ``step_deg`` apart, in scan order.

    Isotropic: a grid over (θ_i, θ_r, Δφ ∈ [0°, 180°]) with ω_i in the
    xz-plane.  Anisotropic: every pair of two Fibonacci spiral caps
    (spacing ≈ ``step_deg``) within the polar limits.
    """
    s = math.radians(step_deg)
    if isotropic:
        ti = np.linspace(0.0, math.radians(max_theta_i_deg), max(2, round(max_theta_i_deg / step_deg) + 1))
        tr = np.linspace(0.0, math.radians(max_theta_r_deg), max(2, round(max_theta_r_deg / step_deg) + 1))
        ph = np.linspace(0.0, math.pi, max(2, round(180.0 / step_deg) + 1))
        TI, TR, PH = (a.ravel() for a in np.meshgrid(ti, tr, ph, indexing="ij"))
        wi = np.stack([np.sin(TI), np.zeros_like(TI), np.cos(TI)], axis=-1)
        wo = np.stack([np.sin(TR) * np.cos(PH), np.sin(TR) * np.sin(PH), np.cos(TR)], axis=-1)
        return wi, wo
    cap_i, cap_r = _fibonacci_cap(max_theta_i_deg, s), _fibonacci_cap(max_theta_r_deg, s)
    i, r = np.meshgrid(np.arange(len(cap_i)), np.arange(len(cap_r)), indexing="ij")
    return cap_i[i.ravel()], cap_r[r.ravel()]


def _fibonacci_cap(max_theta_deg: float, spacing_rad: float) -> np.ndarray:
    """Points on the spherical cap θ ≤ max with about ``spacing_rad`` between neighbours, pole first."""
    area = 2 * math.pi * (1 - math.cos(math.radians(max_theta_deg)))
    n = max(1, round(area / spacing_rad ** 2))
    k = np.arange(n) + 0.5
    z = 1.0 - k / n * (1 - math.cos(math.radians(max_theta_deg)))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    rho = np.sqrt(1 - z ** 2)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=-1)


def motor_candidates(geometry: RigGeometry, step_deg: float, *, isotropic: bool,
                     max_theta_r_deg: float = 65.0) -> np.ndarray:
    """Motor angles ``(N, 4)`` scanning every motor over its range in ``step_deg`` increments (the thesis' way).

    Isotropic samples do not need the roll motor (it only spins the sample
    about its normal), so it stays at 0.  Pan and tilt are scanned only where
    the camera can be within ``max_theta_r_deg`` of the normal (plus a margin
    for axis offsets).
    """
    lim = geometry.limits
    reach = max_theta_r_deg + 10.0

    def axis(k: int, clip: float | None = None) -> np.ndarray:
        lo, hi = lim[k]
        if clip is not None:
            lo, hi = max(lo, -clip), min(hi, clip)
        return np.arange(lo, hi + 1e-9, step_deg)

    roll = np.array([0.0]) if isotropic else axis(2)
    grids = np.meshgrid(axis(3), axis(1, reach), axis(0, reach), roll, indexing="ij")  # light outermost
    light, tilt, pan, roll = (g.ravel() for g in grids)
    return np.stack([pan, tilt, roll, light], axis=-1)


@dataclass(frozen=True)
class PosePlan:
    """Poses chosen by :func:`plan_poses`; arrays share their first axis."""

    angles_deg: np.ndarray   # (K, 4) pan, tilt, roll, light
    wi: np.ndarray           # (K, 3) at the sample centre
    wo: np.ndarray           # (K, 3)
    theta_d_deg: float
    isotropic: bool
    candidates: int          # how many candidates the chooser saw

    def __len__(self) -> int:
        return len(self.angles_deg)


def plan_poses(geometry: RigGeometry, theta_d_deg: float, *, isotropic: bool, step_deg: float | None = None,
               source: str = "directions", max_theta_i_deg: float = 75.0, max_theta_r_deg: float = 65.0) -> PosePlan:
    """Greedy pose plan for ``geometry`` at angular density ``theta_d_deg``.

    ``source="motors"`` scans the motors in ``step_deg`` increments as the
    thesis did (default step 1°; expensive for small θ_d); ``"directions"``
    scans a quasi-uniform set of direction pairs (default step θ_d / 3),
    keeps those the rig can reach, and solves the motor angles of the chosen
    ones with :func:`~sbrdf_lib.rig_geometry.inverse`.
    """
    if source == "motors":
        angles = motor_candidates(geometry, step_deg or 1.0, isotropic=isotropic, max_theta_r_deg=max_theta_r_deg)
        wi, wo = forward(geometry, *angles.T).directions()
        keep = choose_poses(wi, wo, theta_d_deg, isotropic=isotropic, max_theta_i_deg=max_theta_i_deg,
                            max_theta_r_deg=max_theta_r_deg)
        return PosePlan(angles[keep], wi[keep], wo[keep], float(theta_d_deg), isotropic, len(angles))
    if source != "directions":
        raise ValueError(f"source must be 'motors' or 'directions', got {source!r}")
    wi, wo = direction_candidates(step_deg or theta_d_deg / 3.0, isotropic=isotropic,
                                  max_theta_i_deg=max_theta_i_deg, max_theta_r_deg=max_theta_r_deg)
    lo, hi = np.deg2rad(geometry.light_limits_deg)
    phase = _angle(wi, wo)
    reachable = (phase >= lo) & (phase <= hi)  # the light-camera angle is the light arm's (exact without offsets)
    wi, wo = wi[reachable], wo[reachable]
    keep = choose_poses(wi, wo, theta_d_deg, isotropic=isotropic, max_theta_i_deg=max_theta_i_deg,
                        max_theta_r_deg=max_theta_r_deg)
    solution = inverse(geometry, wi[keep], wo[keep])
    ok = solution.reachable
    return PosePlan(solution.angles_deg[ok], wi[keep][ok], wo[keep][ok], float(theta_d_deg), isotropic, len(wi))


# =====================================================================================================
# Exposure brackets (§3.4.1)
# =====================================================================================================


def mirror_angle_deg(wi, wo) -> np.ndarray:
    """Angle between the view direction and the mirror direction of ω_i (0 at the specular peak)."""
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    mirror = wi * np.array([-1.0, -1.0, 1.0])
    return np.rad2deg(_angle(mirror, wo))


def plan_exposures(wi, wo, *, diffuse_time_s: float, highlight_time_s: float, highlight_halfwidth_deg: float = 7.84,
                   field_halfwidth_deg: float = 8.0, stops_per_exposure: float = 3.0, max_exposures: int = 3,
                   min_time_s: float = 2.0 ** -11, max_time_s: float = 0.5) -> np.ndarray:
    """Shutter times per pose, ``(N, max_exposures)`` seconds, NaN-padded; 1 to ``max_exposures`` per pose.

    The operator picks ``diffuse_time_s`` (exposes the darkest pose's diffuse
    reflection, at normal incidence) and ``highlight_time_s`` (exposes the
    brightest highlight).  Per pose, the brightest point in view is predicted
    from the angle ``α`` between the view and mirror directions: the highlight
    (a ``cos^n`` lobe whose half-width at 30% is ``highlight_halfwidth_deg``)
    can appear anywhere within ``field_halfwidth_deg`` of the sample centre,
    so its predicted peak is ``cos^n(max(0, α − field))``.  The diffuse
    exposure grows as ``1 / cos θ_i``.  The bracket spans the two times in
    steps of at most ``stops_per_exposure`` stops; times are whole stops
    (powers of two, as the thesis' 2⁻¹¹ … 2⁻¹ s) clamped to the shutter range.
    """
    wi, wo = np.atleast_2d(wi), np.atleast_2d(wo)
    exponent = math.log(0.3) / math.log(math.cos(math.radians(highlight_halfwidth_deg)))
    alpha = np.maximum(mirror_angle_deg(wi, wo) - field_halfwidth_deg, 0.0)
    peak = np.cos(np.deg2rad(np.minimum(alpha, 89.0))) ** exponent
    cos_i = np.clip(wi[:, 2], math.cos(math.radians(85.0)), 1.0)
    longest = np.log2(diffuse_time_s / cos_i)
    shortest = np.minimum(np.log2(highlight_time_s / np.maximum(peak, 1e-30)), longest)
    lo_stop, hi_stop = math.ceil(math.log2(min_time_s) - 1e-9), math.floor(math.log2(max_time_s) + 1e-9)
    longest = np.clip(np.round(longest), lo_stop, hi_stop)
    shortest = np.clip(np.round(shortest), lo_stop, hi_stop)
    span = longest - shortest
    count = np.clip(1 + np.ceil(span / stops_per_exposure - 1e-9), 1, max_exposures).astype(int)
    out = np.full((len(wi), max_exposures), np.nan)
    for k in range(max_exposures):
        use = k < count
        frac = np.where(count > 1, k / np.maximum(count - 1, 1), 0.0)
        stop = np.where(count > 1, np.round(shortest + frac * span), longest)
        out[use, k] = 2.0 ** stop[use]
    return out
