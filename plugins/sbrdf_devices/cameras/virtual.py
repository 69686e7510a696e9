"""virtual-camera: a simulated camera photographing a known SBRDF on a fiducial carrier.

There is no physical gonioreflectometer in this project, so end-to-end tests
need a camera whose truth is known (seed 000 notes §19, "a synthetic
acquisition simulator").  This device photographs a flat sample whose
material is any installed BRDF model with per-texel parameter maps (the
procedural pattern of the ``synthetic`` capture, or a ``ParamMaps`` artifact),
mounted on a white carrier printed with a border of ArUco markers, through a
pinhole camera with OpenCV lens distortion, lit by a local point light:

    L = f_r(ω_i, ω_o) · I · cos θ_i / r²          (DESIGN.md)

Every pixel's ray is cast to the sample plane z = 0 (rays are precomputed
once: the intrinsics never change), the texel it hits gives the parameters,
and the model is evaluated for all pixels of a band of rows at once.

**Effects are requested, not assumed.**  ``effects`` lists the imperfections
to simulate; a code path that is not requested is not executed at all (and
:attr:`VirtualCamera.effects_ran` records the ones that were):

==============  ==================================================================
effect          what it does
==============  ==================================================================
``falloff``     per-pixel inverse-square distance and cos θ_i; without it every
                point gets the irradiance of the sample centre
``vignetting``  natural vignetting, ``cos^p`` of the ray's angle to the optical axis
``blur``        Gaussian lens blur (σ ``blur_px`` pixels) of the radiance image
``motor_error`` the true pose differs from the nominal one (sample rotation of
                σ ``motor_rotation_deg``, light offset of σ ``motor_light_mm``);
                the capture records the nominal pose, :meth:`true_pose` the real one
``dark_current`` a fixed per-sensel dark signal rate (signal/s) added to every frame
``black_level`` a fixed per-sensel pedestal (``black_level`` of saturation, 10 % spread
                between sensels) added to every frame whatever its exposure
``noise``       shot noise (``full_well`` electrons at saturation) and read noise
``saturation``  the linear signal clips at 1 (the sensor's full well)
``response``    an 8/16-bit camera response curve (gamma, sRGB or McAllister's cubic)
                and quantisation; without it images are linear float32 (EXR)
``shadowing``   with a ``mesostructure``: points whose ray to the light passes below
                the height field get no direct light (a ray march per point)
``masking``     with a ``mesostructure``: each pixel sees the first intersection of
                its ray with the height field instead of the plane z = 0
==============  ==================================================================

**Mesostructure** (``mesostructure`` parameter, :mod:`sbrdf_lib.mesostructure`):
the sample becomes a height field (mm) with per-texel albedo, each facet shaded in
its own frame; without ``shadowing``/``masking`` it costs one normal lookup per pixel.

Signal model: exposure ``S = L · t · sensitivity``; ``S = 1`` is saturation.
Random effects are seeded per pose (motor error) and per pose and exposure
(noise), so a resumed capture reproduces the same images bit for bit.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from sbrdf_core.errors import ParameterError

from ..declarations import EFFECTS, VIRTUAL

if TYPE_CHECKING:
    from sbrdf_core.contracts import BRDFModel
    from sbrdf_lib.mesostructure import Mesostructure
    from sbrdf_lib.response import ResponseCurve

logger = logging.getLogger(__name__)

#: Effects that need a mesostructure to act on.
MESOSTRUCTURE_EFFECTS = ("shadowing", "masking")
WHITE_ALBEDO = 0.80
BLACK_ALBEDO = 0.04


def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    import cv2

    R, _ = cv2.Rodrigues(np.asarray(axis_angle, np.float64).reshape(3, 1))
    return R


class VirtualCamera:
    """A simulated camera + sample + point light; see the module docstring.

    Device protocol (what capture code relies on): :meth:`camera_info`,
    :meth:`sample_info`, :meth:`light_info`, :meth:`photograph`; the
    simulator adds :meth:`true_pose`, :meth:`sensor_radiance`, :meth:`dark_frame`.
    """

    params = VIRTUAL

    def __init__(self, *, width: int = 1024, height: int = 768, focal_px: float = 1400.0,
                 principal_point: Sequence[float] | None = None, dist: Sequence[float] = (-0.08, 0.02, 0.0, 0.0, 0.0),
                 sample_size_mm: Sequence[float] = (100.0, 100.0), texels: Sequence[int] = (256, 256),
                 model: str = "lambert", model_params: Mapping = {}, param_maps: str | None = None,  # noqa: B006
                 carrier_margin_mm: float = 20.0, marker_size_mm: float = 14.0, markers_per_side: int = 3,
                 dictionary: str = "DICT_4X4_50", intensity: float = 250000.0, sensitivity: float = 1.0,
                 effects: Sequence[str] = (), response_curve: str = "srgb", response_gamma: float = 2.2,
                 response_coefficients: Sequence[float] = (2.0, -0.05, -0.01), bit_depth: int = 8,
                 record_response: bool = True, full_well: float = 20000.0, read_noise: float = 0.001,
                 dark_current: float = 0.002, black_level: float = 0.02, vignetting_power: float = 4.0, motor_rotation_deg: float = 0.786,
                 motor_light_mm: float = 2.462, blur_px: float = 0.7, seed: int = 0, row_chunk: int = 128,
                 carrier_supersample: int = 4, mesostructure: Mapping | None = None):
        unknown = [e for e in effects if e not in EFFECTS]
        if unknown:
            raise ParameterError(f"virtual-camera: unknown effect(s) {unknown}; known effects: {list(EFFECTS)}")
        needs = [e for e in effects if e in MESOSTRUCTURE_EFFECTS]
        if needs and mesostructure is None:
            raise ParameterError(f"virtual-camera: effect(s) {needs} act on a height field; give a mesostructure")
        self.width, self.height = int(width), int(height)
        cx, cy = principal_point if principal_point is not None else ((self.width - 1) / 2, (self.height - 1) / 2)
        self.K = np.array([[focal_px, 0.0, cx], [0.0, focal_px, cy], [0.0, 0.0, 1.0]])
        self.dist = np.asarray(dist, np.float64)
        size_x, size_y = (float(s) for s in sample_size_mm)  # [x, y], as declared
        n_u, n_v = (int(t) for t in texels)  # [U, V], as declared
        self.size_mm: tuple[float, float] = (size_x, size_y)
        self.texels: tuple[int, int] = (n_u, n_v)
        self.model_name, self.model_params, self.param_maps_path = model, dict(model_params), param_maps
        self.margin, self.marker_mm, self.markers_per_side = carrier_margin_mm, marker_size_mm, markers_per_side
        self.dictionary = dictionary
        self.intensity, self.sensitivity = intensity, sensitivity
        self.effects = tuple(e for e in EFFECTS if e in effects)  # canonical order
        self.response_curve, self.response_gamma = response_curve, response_gamma
        self.response_coefficients, self.bit_depth, self.record_response = list(response_coefficients), bit_depth, record_response
        self.full_well, self.read_noise, self.dark_current = full_well, read_noise, dark_current
        self.black_level = float(black_level)
        self.vignetting_power = vignetting_power
        self.motor_rotation_deg, self.motor_light_mm, self.blur_px = motor_rotation_deg, motor_light_mm, blur_px
        self.seed, self.row_chunk = seed, row_chunk
        self.carrier_supersample = int(carrier_supersample)
        self.mesostructure: Mesostructure | None = None
        if mesostructure is not None:
            from sbrdf_lib.mesostructure import Mesostructure

            self.mesostructure = Mesostructure.from_config(mesostructure, self.texels, self.size_mm)
        if markers_per_side * 4 > self._dictionary_size():
            raise ParameterError(f"virtual-camera: {markers_per_side * 4} markers do not fit {dictionary}")
        if marker_size_mm >= carrier_margin_mm:
            raise ParameterError(f"virtual-camera: marker_size_mm ({marker_size_mm}) must be smaller than carrier_margin_mm "
                                 f"({carrier_margin_mm}) so markers keep a white quiet zone")
        self.model: BRDFModel | None = None
        self.effects_ran: set[str] = set()
        self.true_poses: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._maps: dict[str, np.ndarray] | None = None
        self._rays: np.ndarray | None = None
        self._carrier: tuple[np.ndarray, float] | None = None
        self._curve: ResponseCurve | None = None
        self._cache: tuple[Any, np.ndarray] | None = None

    # -- plugins ---------------------------------------------------------------------

    def bind(self, registry) -> None:
        """Resolve the BRDF model (and parameter maps) through a registry."""
        if self.param_maps_path:
            from sbrdf_core.store import open_artifact

            art = open_artifact(self.param_maps_path, kind="ParamMaps")
            model = self.model = registry.create("brdf-model", art.attrs["model"], dict(art.attrs.get("model_config", {})))
            self._maps = {p.name: np.asarray(art.read(f"params/{p.name}"), np.float64) for p in model.parameters}
            V, U = next(iter(self._maps.values())).shape[:2]
            self.texels = (U, V)
        else:
            self.model = registry.create("brdf-model", self.model_name, self.model_params)

    def _ensure_model(self) -> BRDFModel:
        """The material's BRDF model, bound through the default registry if no run bound this camera."""
        if self.model is None:
            from sbrdf_core.registry import default_registry

            self.bind(default_registry())
        assert self.model is not None, "bind() sets the model"
        return self.model

    def ground_truth(self) -> dict[str, np.ndarray]:
        """The material's parameter maps, ``name -> (V, U, C)``."""
        model = self._ensure_model()
        if self._maps is None:
            from sbrdf_lib.patterns import pattern

            n_u, n_v = self.texels
            self._maps = {}
            for k, p in enumerate(model.parameters):
                lo, hi = p.typical
                self._maps[p.name] = np.stack([lo + (hi - lo) * pattern(n_u, n_v, k, c) for c in range(p.channels)], axis=-1)
        return self._maps

    def reference_f_r(self, texels_uv: tuple[int, int], light_pos: np.ndarray, camera_pos: np.ndarray,
                      rows: tuple[int, int] | None = None, cols: tuple[int, int] | None = None) -> np.ndarray:
        """The true material's f_r at a texel grid's centres: ``(V', U', P, 3)``, SampledReflectance's layout.

        Each texel centre of the ``texels_uv`` grid over the sample takes the parameters of
        the material texel it lies in, and the model is evaluated at its own ω_i, ω_r
        towards ``light_pos``, ``camera_pos`` (``(P, 3)``, mm, sample frame) — what a
        Reflectance sample of that texel should hold.  ``rows``/``cols`` (``(start, stop)``)
        select part of the grid.
        """
        from sbrdf_core.geometry import texel_centres, tile_directions

        n_u, n_v = texels_uv
        rows = rows if rows is not None else (0, n_v)
        cols = cols if cols is not None else (0, n_u)
        maps = self.ground_truth()
        sx, sy = self.size_mm
        m_u, m_v = self.texels
        p = texel_centres(texels_uv, self.size_mm, rows[0], rows[1], cols[0], cols[1]).reshape(-1, 3)
        u = np.clip(((p[:, 0] + sx / 2) / sx * m_u).astype(np.int64), 0, m_u - 1)
        v = np.clip(((p[:, 1] + sy / 2) / sy * m_v).astype(np.int64), 0, m_v - 1)
        wi, _, wo = tile_directions(texels_uv, self.size_mm, rows, cols, light_pos, camera_pos)
        f = self._ensure_model().eval({name: m[v, u] for name, m in maps.items()}, wi, wo)
        return f.reshape(rows[1] - rows[0], cols[1] - cols[0], *f.shape[1:])

    # -- manifest sections --------------------------------------------------------------

    def camera_info(self) -> dict:
        """The capture.json ``camera`` section."""
        info: dict[str, Any] = {"width": self.width, "height": self.height, "K": self.K.tolist(), "dist": self.dist.tolist()}
        if "response" not in self.effects:
            info["response"] = "linear"
            if "saturation" in self.effects:
                info["white_level"] = 1.0
        elif self.record_response:
            info["response"] = self.curve().to_manifest()
        return info

    def sample_info(self) -> dict:
        """The capture.json ``sample`` section, with every marker's corners in mm (OpenCV order)."""
        markers = [{"id": i, "corners_mm": c.tolist()} for i, c in enumerate(self.marker_corners_mm())]
        carrier = [s + 2 * self.margin for s in self.size_mm]
        return {"size_mm": list(self.size_mm), "fiducials": {"dictionary": self.dictionary, "markers": markers},
                "carrier_mm": carrier}

    def light_info(self) -> dict:
        return {"type": "point", "intensity": float(self.intensity)}

    def simulation_info(self) -> dict:
        """What was simulated (recorded in the manifest under ``simulation``)."""
        settings: dict[str, Any] = {"sensitivity": self.sensitivity}
        if "response" in self.effects:
            settings.update(response_curve=self.response_curve, bit_depth=self.bit_depth)
        if "noise" in self.effects:
            settings.update(full_well=self.full_well, read_noise=self.read_noise)
        if "dark_current" in self.effects:
            settings["dark_current"] = self.dark_current
        if "black_level" in self.effects:
            settings["black_level"] = self.black_level
        if "vignetting" in self.effects:
            settings["vignetting_power"] = self.vignetting_power
        if "motor_error" in self.effects:
            settings.update(motor_rotation_deg=self.motor_rotation_deg, motor_light_mm=self.motor_light_mm)
        if "blur" in self.effects:
            settings["blur_px"] = self.blur_px
        if self.mesostructure is not None:
            m = self.mesostructure
            settings["mesostructure"] = {"texels": list(m.texels), "height_range_mm": [m.h_min, m.h_max],
                                         "mean_albedo": m.albedo.mean(axis=(0, 1)).tolist(), "facet": m.facet}
        return {"device": "virtual-camera", "model": self._model_label(), "texels": list(self.texels),
                "effects": list(self.effects), "settings": settings, "seed": self.seed}

    def _model_label(self) -> str:
        return self.param_maps_path and f"ParamMaps:{self.param_maps_path}" or self.model_name

    # -- carrier ----------------------------------------------------------------------

    def _dictionary_size(self) -> int:
        import cv2

        if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
            raise ParameterError(f"virtual-camera: unknown ArUco dictionary {self.dictionary!r}")
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]

    def marker_centres_mm(self) -> np.ndarray:
        """Centres of the markers, going round the border band (4 × markers_per_side)."""
        hx, hy = self.size_mm[0] / 2 + self.margin / 2, self.size_mm[1] / 2 + self.margin / 2
        s = np.linspace(0.0, 1.0, self.markers_per_side + 1)[:-1]
        sides = [((-hx, -hy), (hx, -hy)), ((hx, -hy), (hx, hy)), ((hx, hy), (-hx, hy)), ((-hx, hy), (-hx, -hy))]
        return np.array([np.add(a, np.multiply(f, np.subtract(b, a))) for a, b in sides for f in s])

    def marker_corners_mm(self) -> np.ndarray:
        """``(N, 4, 2)`` corners in the marker image's order TL, TR, BR, BL as seen by a camera above."""
        h = self.marker_mm / 2
        # The carrier's print rows run along -y (viewed from +z with x to the right, +y is up).
        offsets = np.array([[-h, h], [h, h], [h, -h], [-h, -h]])
        return self.marker_centres_mm()[:, None, :] + offsets[None]

    def carrier_albedo(self) -> tuple[np.ndarray, float]:
        """The printed carrier as an albedo bitmap (rows along -y) and its pixels per mm."""
        if self._carrier is None:
            import cv2

            ppm = 6.0 / self.marker_mm * 8  # 8 bitmap pixels per marker module
            cw, ch = self.size_mm[0] + 2 * self.margin, self.size_mm[1] + 2 * self.margin
            img = np.full((int(round(ch * ppm)), int(round(cw * ppm))), WHITE_ALBEDO, np.float32)
            d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
            side = int(round(self.marker_mm * ppm))
            for i, corners in enumerate(self.marker_corners_mm()):
                x0, y_top = corners[0]
                col = int(round((x0 + cw / 2) * ppm))
                row = int(round((ch / 2 - y_top) * ppm))
                marker = cv2.aruco.generateImageMarker(d, i, side)
                img[row:row + side, col:col + side] = np.where(marker > 127, WHITE_ALBEDO, BLACK_ALBEDO)
            self._carrier = (img, ppm)
        return self._carrier

    def carrier_albedo_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Albedo of the printed carrier at sample-frame points (mm), exact to the marker modules.

        Looked up analytically (which marker, which of its modules) rather than
        from the :meth:`carrier_albedo` bitmap, whose pixel grid would shift the
        printed markers by up to half a bitmap pixel (≈0.15 mm) from the corners
        the manifest declares: registration tests measure errors smaller than that.
        """
        import cv2

        if getattr(self, "_marker_bits", None) is None:
            d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
            bits = [cv2.aruco.generateImageMarker(d, i, 6) > 127 for i in range(len(self.marker_corners_mm()))]
            self._marker_bits = np.stack(bits)  # (N, 6, 6) incl. the black border, rows top to bottom
        out = np.full(x.shape, WHITE_ALBEDO, np.float32)
        for i, corners in enumerate(self.marker_corners_mm()):
            x0, y_top = corners[0]
            cu = (x - x0) / self.marker_mm * 6
            cv = (y_top - y) / self.marker_mm * 6
            inside = (cu >= 0) & (cu < 6) & (cv >= 0) & (cv < 6)
            if inside.any():
                b = self._marker_bits[i][cv[inside].astype(np.int64), cu[inside].astype(np.int64)]
                out[inside] = np.where(b, WHITE_ALBEDO, BLACK_ALBEDO)
        return out

    def _carrier_pixel_albedo(self, r0, r1, mask, x, y, centre, R) -> np.ndarray:
        """Carrier albedo averaged over each pixel's area (``carrier_supersample``² rays per pixel).

        A sensor integrates over its pixels; point-sampling the printed markers
        would quantise their edges to whole pixels and cap fiducial registration
        at ≈0.3 px RMS whatever the detector does.  Sub-pixel rays come from the
        per-pixel ray and its derivatives (distortion is smooth at that scale);
        a sub-ray that leaves the carrier keeps the pixel-centre albedo.
        """
        n = self.carrier_supersample
        centre_albedo = self.carrier_albedo_at(x, y)
        if n <= 1:
            return centre_albedo
        if getattr(self, "_ray_grad", None) is None:
            rays = self.rays()
            self._ray_grad = (np.gradient(rays, axis=1), np.gradient(rays, axis=0))
        rays = self.rays()[r0:r1][mask]
        du, dv = self._ray_grad[0][r0:r1][mask], self._ray_grad[1][r0:r1][mask]
        sx, sy = self.size_mm
        cw, ch = sx + 2 * self.margin, sy + 2 * self.margin
        acc = np.zeros(x.shape, np.float64)
        offsets = (np.arange(n) + 0.5) / n - 0.5
        for ou in offsets:
            for ov in offsets:
                d = (rays + ou * du + ov * dv) @ R
                with np.errstate(divide="ignore", invalid="ignore"):
                    s = -centre[2] / d[..., 2]
                X = centre + s[..., None] * d
                xs, ys = X[..., 0], X[..., 1]
                band = (s > 0) & (np.abs(xs) < cw / 2) & (np.abs(ys) < ch / 2) & ~((np.abs(xs) < sx / 2) & (np.abs(ys) < sy / 2))
                a = centre_albedo.astype(np.float64).copy()
                if band.any():
                    a[band] = self.carrier_albedo_at(xs[band], ys[band])
                acc += a
        return (acc / (n * n)).astype(np.float32)

    # -- optics -----------------------------------------------------------------------

    def rays(self) -> np.ndarray:
        """Per-pixel ray directions ``(H, W, 3)`` in camera coordinates, ``(x', y', 1)`` (undistorted)."""
        if self._rays is None:
            import cv2

            v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
            pts = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
            if np.any(self.dist):
                crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
                norm = cv2.undistortPoints(pts, self.K, self.dist, None, None, None, crit).reshape(self.height, self.width, 2)
            else:
                norm = np.stack([(u - self.K[0, 2]) / self.K[0, 0], (v - self.K[1, 2]) / self.K[1, 1]], axis=-1)
            self._rays = np.concatenate([norm, np.ones((self.height, self.width, 1))], axis=-1)
        return self._rays

    def vignetting(self) -> np.ndarray:
        """``(H, W)`` natural-vignetting factor ``cos^p`` of each ray's angle to the axis."""
        r = self.rays()
        return (1.0 / np.linalg.norm(r, axis=-1)) ** self.vignetting_power

    def curve(self) -> ResponseCurve:
        if self._curve is None:
            from sbrdf_lib.response import ResponseCurve, response_table

            self._curve = ResponseCurve(response_table(self.response_curve, self.bit_depth, self.response_gamma,
                                                       self.response_coefficients))
        return self._curve

    # -- poses ------------------------------------------------------------------------

    def _pose_key(self, light_pos, R, t) -> int:
        h = hashlib.blake2b(np.concatenate([np.ravel(light_pos), np.ravel(R), np.ravel(t)]).astype(np.float64).tobytes(),
                            digest_size=8)
        return int.from_bytes(h.digest(), "little") >> 1

    def true_pose(self, light_pos_mm, R, t, pose_id: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pose the rig really reached for a nominal one (identity without ``motor_error``).

        The sample is rotated by a small random rotation ΔR about its centre
        (sample pan/tilt/roll repeatability), so the camera sees ``R ΔR`` and the
        light sits at ``ΔRᵀ light`` plus a random offset (light-arm repeatability).
        Seeded by the pose, so every exposure of a bracket shares it.
        """
        light = np.asarray(light_pos_mm, np.float64).reshape(3)
        R = np.asarray(R, np.float64).reshape(3, 3)
        t = np.asarray(t, np.float64).reshape(3)
        if "motor_error" not in self.effects:
            return light, R, t
        self.effects_ran.add("motor_error")
        key = pose_id if pose_id is not None else self._pose_key(light, R, t)
        rng = np.random.default_rng([self.seed, 1, key])
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        dR = _rotation(axis * np.radians(self.motor_rotation_deg) * rng.standard_normal())
        true = (dR.T @ light + self.motor_light_mm * rng.standard_normal(3), R @ dR, t.copy())
        if pose_id is not None:
            self.true_poses[pose_id] = true
        return true

    # -- rendering --------------------------------------------------------------------

    def sensor_radiance(self, light_pos_mm, R, t, pose_id: int | None = None) -> np.ndarray:
        """Radiance reaching each pixel, ``(H, W, 3) float32``, after the optics (vignetting, blur).

        The folder reader's HDR radiance of a noise-free capture equals this.
        Cached for the last pose, so the exposures of a bracket render once.
        """
        key = (pose_id, np.asarray(light_pos_mm, float).tobytes(), np.asarray(R, float).tobytes(), np.asarray(t, float).tobytes())
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        light, Rt, tt = self.true_pose(light_pos_mm, R, t, pose_id)
        out: np.ndarray = np.empty((self.height, self.width, 3), np.float32)
        for r0 in range(0, self.height, self.row_chunk):
            r1 = min(r0 + self.row_chunk, self.height)
            out[r0:r1] = self._render_rows(r0, r1, light, Rt, tt)
        if "blur" in self.effects and self.blur_px > 0:
            import cv2

            self.effects_ran.add("blur")
            out = cv2.GaussianBlur(out, (0, 0), sigmaX=self.blur_px, sigmaY=self.blur_px, borderType=cv2.BORDER_REFLECT)
        self._cache = (key, out)
        return out

    def _render_rows(self, r0: int, r1: int, light: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        model = self._ensure_model()
        centre = -R.T @ t
        d = self.rays()[r0:r1] @ R  # world directions (Rᵀ d for every pixel)
        dz = d[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(dz != 0, -centre[2] / dz, -1.0)
        hit = s > 0
        X = centre + s[..., None] * d
        if self.mesostructure is not None:
            X, hit = self._meso_points(X, hit, centre, d)
        x, y = X[..., 0], X[..., 1]
        sx, sy = self.size_mm
        cw, ch = sx + 2 * self.margin, sy + 2 * self.margin
        on_sample = hit & (np.abs(x) < sx / 2) & (np.abs(y) < sy / 2)
        on_carrier = hit & ~on_sample & (np.abs(x) < cw / 2) & (np.abs(y) < ch / 2)
        wo = centre - X
        wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
        lv = light - X
        r = np.linalg.norm(lv, axis=-1)
        wi = lv / r[..., None]
        L = np.zeros(x.shape + (3,), np.float64)

        # Material: gather each hit texel's parameters, evaluate the model for all of them at once.
        if on_sample.any() and self.mesostructure is not None:
            L[on_sample] = self._meso_radiance(X[on_sample], wi[on_sample], wo[on_sample], light)
        elif on_sample.any():
            maps = self.ground_truth()
            n_u, n_v = self.texels
            u = np.clip(((x[on_sample] + sx / 2) / sx * n_u).astype(np.int64), 0, n_u - 1)
            v = np.clip(((y[on_sample] + sy / 2) / sy * n_v).astype(np.int64), 0, n_v - 1)
            params = {name: m[v, u] for name, m in maps.items()}
            f = model.eval(params, wi[on_sample][:, None], wo[on_sample][:, None])[:, 0]
            L[on_sample] = f
        if on_carrier.any():
            up = (wi[on_carrier][:, 2] > 0) & (wo[on_carrier][:, 2] > 0)
            albedo = self._carrier_pixel_albedo(r0, r1, on_carrier, x[on_carrier], y[on_carrier], centre, R)
            L[on_carrier] = (albedo / np.pi * up)[:, None]

        if "falloff" in self.effects:
            self.effects_ran.add("falloff")
            E = self.intensity * np.clip(wi[..., 2], 0.0, None) / r**2
        else:  # the sample centre's irradiance everywhere
            rc = np.linalg.norm(light)
            E = np.full(x.shape, self.intensity * max(light[2] / rc, 0.0) / rc**2)
        L *= E[..., None]
        if "vignetting" in self.effects:
            self.effects_ran.add("vignetting")
            L *= (1.0 / np.linalg.norm(self.rays()[r0:r1], axis=-1) ** self.vignetting_power)[..., None]
        return L.astype(np.float32)

    def _meso_points(self, X, hit, centre, d):
        """Surface points of a mesostructure: above the plane hit, or the first ray hit with ``masking``."""
        m = self.mesostructure
        assert m is not None, "called only for a camera with a mesostructure"
        if "masking" in self.effects:
            self.effects_ran.add("masking")
            dn = d / np.linalg.norm(d, axis=-1, keepdims=True)
            flat = dn.reshape(-1, 3)
            pts, got = m.first_hit(np.broadcast_to(centre, flat.shape), flat)
            return pts.reshape(X.shape), got.reshape(hit.shape)
        X = X.copy()
        X[..., 2] = np.where(hit, m.height_at(X[..., 0], X[..., 1]), 0.0)
        return X, hit

    def _meso_radiance(self, X, wi, wo, light) -> np.ndarray:
        """``f_r · cos θ_i' / cos θ_i`` per point: facet BRDF, facet cosine over the plane's (falloff multiplies back)."""
        m = self.mesostructure
        assert m is not None, "called only for a camera with a mesostructure"
        v, u = m.texel_index(X[:, 0], X[:, 1])
        frame = m.facet_frame(v, u)
        wi_l, wo_l = m.to_local(wi, frame), m.to_local(wo, frame)
        if m.facet == "lambert":
            f = m.albedo[v, u] / np.pi
        else:
            maps = self.ground_truth()
            n_u, n_v = self.texels
            sx, sy = self.size_mm
            pu = np.clip(((X[:, 0] + sx / 2) / sx * n_u).astype(np.int64), 0, n_u - 1)
            pv = np.clip(((X[:, 1] + sy / 2) / sy * n_v).astype(np.int64), 0, n_v - 1)
            f = m.albedo[v, u] * self._ensure_model().eval({k: a[pv, pu] for k, a in maps.items()}, wi_l[:, None], wo_l[:, None])[:, 0]
        lit = (wi_l[:, 2] > 0) & (wo_l[:, 2] > 0) & (wi[:, 2] > 0)
        if "shadowing" in self.effects:
            self.effects_ran.add("shadowing")
            lit &= ~m.shadowed(X, np.broadcast_to(light, X.shape))
        ratio = np.where(lit, wi_l[:, 2] / np.where(wi[:, 2] > 0, wi[:, 2], 1.0), 0.0)
        return f * ratio[:, None]

    # -- the sensor ---------------------------------------------------------------------

    def _dark_rate(self) -> np.ndarray:
        """Fixed-pattern dark-current rate per sensel and channel (signal/s), from the camera seed."""
        if getattr(self, "_dark_rate_map", None) is None:
            rng = np.random.default_rng([self.seed, 3])
            self._dark_rate_map = (self.dark_current * rng.gamma(4.0, 0.25, (self.height, self.width, 3))).astype(np.float32)
        return self._dark_rate_map

    def _black_level(self) -> np.ndarray:
        """Fixed-pattern pedestal per sensel and channel (signal), from the camera seed."""
        if getattr(self, "_black_level_map", None) is None:
            rng = np.random.default_rng([self.seed, 5])
            spread = 1.0 + 0.1 * rng.standard_normal((self.height, self.width, 3))
            self._black_level_map = (self.black_level * spread).astype(np.float32)
        return self._black_level_map

    def _sensor(self, L: np.ndarray, exposure_s: float, noise_key: Sequence[int], stream: int = 2) -> np.ndarray:
        S: np.ndarray = L * np.float32(exposure_s * self.sensitivity)
        if "dark_current" in self.effects:
            self.effects_ran.add("dark_current")
            S = S + self._dark_rate() * np.float32(exposure_s)
        if "black_level" in self.effects:
            self.effects_ran.add("black_level")
            S = S + self._black_level()
        if "noise" in self.effects:
            self.effects_ran.add("noise")
            rng = np.random.default_rng([self.seed, stream, *noise_key])
            sigma = np.sqrt(np.maximum(S, 0.0) / np.float32(self.full_well) + np.float32(self.read_noise) ** 2)
            S = S + sigma * rng.standard_normal(S.shape, dtype=np.float32)
        if "saturation" in self.effects or "response" in self.effects:
            self.effects_ran.add("saturation")
            S = np.minimum(S, np.float32(1.0))
        if "response" in self.effects:
            self.effects_ran.add("response")
            return self.curve().expose(np.clip(S, 0.0, 1.0))
        return S.astype(np.float32)

    def photograph(self, light_pos_mm, R, t, exposure_s: float, *, pose_id: int | None = None,
                   exposure_index: int = 0) -> np.ndarray:
        """One photograph at the nominal pose: ``(H, W, 3)``, uint8/uint16 with a response, else float32.

        ``pose_id`` and ``exposure_index`` seed the random effects (a hash of the
        pose is used without an id), so re-taking a pose gives the same image.
        """
        if not exposure_s > 0:
            raise ParameterError(f"virtual-camera: exposure time must be positive, got {exposure_s!r}")
        if pose_id is not None and pose_id < 0:
            raise ParameterError(f"virtual-camera: pose_id must be non-negative, got {pose_id}")
        logger.debug("virtual-camera: photograph pose %s exposure %d (%g s)", pose_id, exposure_index, exposure_s)
        L = self.sensor_radiance(light_pos_mm, R, t, pose_id)
        key = pose_id if pose_id is not None else self._pose_key(light_pos_mm, R, t)
        return self._sensor(L, exposure_s, (key, exposure_index))

    def dark_frame(self, exposure_s: float, frame_id: int = 0) -> np.ndarray:
        """A lens-capped frame (no light): dark current, black level and noise only, through the same sensor."""
        L = np.zeros((self.height, self.width, 3), np.float32)
        return self._sensor(L, exposure_s, (frame_id, 0), stream=4)

    def flat_frame(self, exposure_s: float, frame_id: int = 0) -> np.ndarray:
        """A frame of a uniform target filling the view (a diffuser on the lens, an integrating sphere's port).

        The target's radiance puts the signal of an on-axis pixel at half of
        saturation at ``exposure_s``; the optics (vignetting) and the sensor
        (dark current, black level, noise, response) act on it as on a
        photograph.
        """
        if not exposure_s > 0:
            raise ParameterError(f"virtual-camera: exposure time must be positive, got {exposure_s!r}")
        L = np.full((self.height, self.width, 3), 0.5 / (exposure_s * self.sensitivity), np.float32)
        if "vignetting" in self.effects:
            L *= self.vignetting()[..., None].astype(np.float32)
        return self._sensor(L, exposure_s, (frame_id, 0), stream=6)

