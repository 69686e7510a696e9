"""Light-arc acquisition (seed 002 §3.1): a fixed orthogonal view, the light on an arc in ~10° steps.

Two capture sources, both plain configurations of existing parts:

* ``light-arc`` drives the simulated (or real) gonioreflectometer: the
  ``gonio`` source with the sample facing the camera (pan = tilt = roll = 0)
  and only the light arm moving; :func:`light_arc_angles` turns wanted light
  elevations θ_i at the sample centre into arm angles (the carrier's stand-off
  from the pan axis shifts them slightly).  Everything else (motors, camera
  device, exposures, folder) is the ``gonio`` source's own configuration, so
  the virtual camera with a ``mesostructure`` photographs a real height field.
* ``mesostructure-arc`` is the fast, texel-aligned simulator (like
  ``synthetic``): pixel (u, v) is the radiance that texel (u, v) of a height
  field sends straight up, under a point light on the arc; pair it with the
  ``texel-aligned`` registration.  Self-shadowing is computed only when
  ``shadowing`` is true.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from sbrdf_core.errors import ParameterError
from sbrdf_core.types import PluginRegistry

from .declarations import LIGHT_ARC, MESOSTRUCTURE_ARC

logger = logging.getLogger(__name__)

#: Light elevations θ_i from the normal, degrees: 10° steps, as in the paper (the rig's arm cannot reach 5°).
DEFAULT_ARC = (15.0, 25.0, 35.0, 45.0, 55.0, 65.0, 75.0, 85.0)


def light_arc_angles(theta_i_deg=DEFAULT_ARC, geometry=None) -> np.ndarray:
    """Rig motor angles ``(P, 4)`` [pan, tilt, roll, light] putting the light at ``theta_i_deg`` from the normal.

    At pan = tilt = roll = 0 the sample faces the camera and its centre sits ``s`` (the
    stand-off) in front of the pan axis, about which the arm of length ``d`` swings; the
    triangle (axis, sample, light) gives the arm angle ``a = θ − asin(s sin θ / d)``.
    Raises ``ValueError`` when an angle is outside the arm's limits.
    """
    from sbrdf_lib.rig_geometry import RigGeometry

    g = geometry if geometry is not None else RigGeometry()
    theta = np.radians(np.asarray(theta_i_deg, np.float64).reshape(-1))
    if not len(theta) or not np.all((theta > 0) & (theta < np.pi / 2)):
        raise ValueError(f"theta_i_deg must be a non-empty list of angles in (0, 90), got {list(np.degrees(theta))}")
    if any(abs(x) > 1e-9 for x in (g.light_height_mm, g.camera_height_mm, *g.tilt_axis_offset_mm, *g.sample_center_offset_mm)):
        raise ValueError("light_arc_angles assumes the light arm, camera and sample centre in one horizontal plane "
                         "(zero heights and offsets in the rig geometry)")
    arm = np.degrees(theta - np.arcsin(g.sample_standoff_mm * np.sin(theta) / g.light_distance_mm)) + g.light_zero_deg
    lo, hi = g.light_limits_deg
    bad = (arm < lo) | (arm > hi)
    if bad.any():
        raise ValueError(f"light elevations {list(np.degrees(theta[bad]))} need arm angles {list(arm[bad])} outside the "
                         f"arm's limits [{lo}, {hi}]")
    out = np.zeros((len(theta), 4))
    out[:, :3] = [g.pan_zero_deg, g.tilt_zero_deg, g.roll_zero_deg]
    out[:, 3] = arm
    return out


class LightArcCapture:
    """``light-arc``: the ``gonio`` source with a light-arc plan (see the module docstring)."""

    sequential = True

    params = LIGHT_ARC

    def __init__(self, *, theta_i_deg=list(DEFAULT_ARC), path: str, motors: dict,  # noqa: B006 (read only)
                 camera={"device": "virtual-camera", "params": {}}, light=None, geometry={},  # noqa: B006 (read only)
                 exposures={"times_s": [1.0]}, read={}, settle_s: float = 0.0, image_format: str = "png",  # noqa: B006
                 durable: bool = True):
        self.theta_i_deg = [float(t) for t in theta_i_deg]
        # The gonio source's own parameters, passed through (its plan is the light arc).
        self.gonio_params = {"path": path, "motors": motors, "camera": camera, "light": light, "geometry": geometry,
                             "exposures": exposures, "read": read, "settle_s": settle_s, "image_format": image_format,
                             "durable": durable}
        #: The ``gonio`` capture source (another plugin's, so reached through the registry), made in :meth:`bind`.
        self.source: Any = None

    def bind(self, registry: PluginRegistry) -> None:
        from sbrdf_lib.rig_geometry import RigGeometry

        geometry = self.gonio_params.get("geometry") or {}
        try:
            values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in geometry.items()}
            g = RigGeometry(**values)
            angles = light_arc_angles(self.theta_i_deg, g)
        except (TypeError, ValueError) as e:
            raise ParameterError(f"light-arc: {e}") from None
        self.source = registry.create("capture", "gonio", {**self.gonio_params, "plan": {"angles_deg": angles.tolist()}})
        self.source.bind(registry)

    def _ensure(self):
        if self.source is None:
            from sbrdf_core.registry import default_registry

            self.bind(default_registry())
        return self.source

    def __dask_tokenize__(self):
        return ("sbrdf-light-arc", tuple(self.theta_i_deg), str(self.gonio_params.get("path")), id(self))

    def describe(self):
        return self._ensure().describe()

    def read_pose(self, index: int):
        return self._ensure().read_pose(index)


class MesostructureArcCapture:
    """``mesostructure-arc``: texel-aligned images of a height field under a light on an arc."""

    params = MESOSTRUCTURE_ARC

    def __init__(self, *, texels=[128, 128], size_mm=[20.0, 20.0],  # noqa: B006 (read only)
                 mesostructure={"height_mm": {"procedural": "bumps", "amplitude_mm": 0.3, "period_mm": 2.0},  # noqa: B006
                                "albedo": 0.7},
                 theta_i_deg=list(DEFAULT_ARC), azimuth_deg: float = 0.0,  # noqa: B006 (read only)
                 light_distance_mm: float = 1000.0,
                 camera_distance_mm: float = 1000.0, intensity: float | None = None, shadowing: bool = False):
        from sbrdf_lib.mesostructure import Mesostructure

        self.texels, self.size_mm = tuple(texels), tuple(size_mm)
        self.meso = Mesostructure.from_config(mesostructure, self.texels, self.size_mm)
        self.theta = np.radians(np.asarray(theta_i_deg, np.float64))
        if not len(self.theta) or not np.all((self.theta >= 0) & (self.theta < np.pi / 2)):
            raise ParameterError(f"mesostructure-arc: theta_i_deg must be angles in [0, 90), got {theta_i_deg}")
        self.azimuth = math.radians(azimuth_deg)
        self.light_distance, self.camera_distance = light_distance_mm, camera_distance_mm
        self.intensity = intensity if intensity is not None else light_distance_mm**2
        self.shadowing = shadowing

    def light_positions(self) -> np.ndarray:
        t, a = self.theta, self.azimuth
        return self.light_distance * np.stack([np.sin(t) * math.cos(a), np.sin(t) * math.sin(a), np.cos(t)], axis=-1)

    def describe(self):
        from sbrdf_core.geometry import look_at
        from sbrdf_core.types import CaptureDescription

        n_u, n_v = self.texels
        P = len(self.theta)
        R, t = look_at(np.array([0.0, 0.0, self.camera_distance]))
        f = n_u / (self.size_mm[0] / self.camera_distance)
        return CaptureDescription(
            height=n_v, width=n_u, light_pos=self.light_positions(),
            camera_R=np.repeat(R[None], P, axis=0), camera_t=np.repeat(t[None], P, axis=0),
            exposure_s=np.ones(P),
            sample={"size_mm": list(self.size_mm), "fiducials": None},
            camera={"width": n_u, "height": n_v, "K": [[f, 0, n_u / 2], [0, f, n_v / 2], [0, 0, 1]],
                    "dist": [0, 0, 0, 0, 0], "response": "linear", "model": "texel-aligned"},
            light={"type": "point", "intensity": self.intensity},
        )

    def read_pose(self, index: int):
        return render_arc_image(self.meso, self.light_positions()[index], self.intensity, self.texels, self.size_mm,
                                self.shadowing), np.ones(self.texels[::-1], bool)


def render_arc_image(meso, light_pos, intensity: float, texels, size_mm, shadowing: bool) -> np.ndarray:
    """Texel-aligned radiance ``(V, U, 3) float32`` of a Lambertian height field seen from straight above.

    ``L = albedo/π · max(n·ω_i, 0) · I / r²``, zero where shadowed (only with ``shadowing``).
    """
    from sbrdf_core.geometry import texel_centres

    p = texel_centres(texels, size_mm).reshape(-1, 3)
    p[:, 2] = meso.height_at(p[:, 0], p[:, 1])
    v, u = meso.texel_index(p[:, 0], p[:, 1])
    d = np.asarray(light_pos, np.float64)[None] - p
    r2 = (d * d).sum(-1)
    wi = d / np.sqrt(r2)[:, None]
    cos = np.clip((wi * meso.normal[v, u]).sum(-1), 0.0, None)
    if shadowing:
        cos = np.where(meso.shadowed(p, np.broadcast_to(light_pos, p.shape)), 0.0, cos)
    L = meso.albedo[v, u] / np.pi * (cos * intensity / r2)[:, None]
    return L.reshape(texels[1], texels[0], 3).astype(np.float32)
