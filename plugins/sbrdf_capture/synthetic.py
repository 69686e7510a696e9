"""synthetic: a simulated capture of a procedural material, for demos and tests.

The material is any installed BRDF model with smooth, checkered parameter maps
spanning each parameter's ``typical`` range.  Images are *texel-aligned*: pixel
(u, v) is the radiance texel (u, v) sends toward the camera, i.e. what a
perfect registration would produce; pair it with the ``texel-aligned``
registration.  Each pose is computed independently (noise seeded per pose), so
an interrupted capture resumes to the same result.

Radiance per texel: L = f_r(ω_i, ω_o) · I · cos θ_i / r² (DESIGN.md).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from sbrdf_core.geometry import directions_to, fibonacci_hemisphere, look_at, texel_centres
from sbrdf_core.types import CaptureDescription
from sbrdf_lib.patterns import pattern  # re-exported: sbrdf_capture.synthetic.pattern is its old home

from .declarations import SYNTHETIC

if TYPE_CHECKING:
    from sbrdf_core.contracts import BRDFModel


class SyntheticCapture:
    """Simulated gonioreflectometer capture of a procedural material."""

    params = SYNTHETIC

    def __init__(self, *, texels: Sequence[int] = (64, 64), size_mm: Sequence[float] = (100.0, 100.0), poses: int = 48,
                 model: str = "lambert", model_params: dict = {}, light_distance_mm: float = 600.0,  # noqa: B006
                 camera_distance_mm: float = 800.0, max_theta_deg: float = 75.0, intensity: float | None = None,
                 noise: float = 0.0, saturation: float | None = None, seed: int = 0, pose_delay_s: float = 0.0):
        n_u, n_v = texels  # [U, V], as declared
        size_x, size_y = size_mm  # [x, y], as declared
        self.texels: tuple[int, int] = (n_u, n_v)
        self.size_mm: tuple[float, float] = (size_x, size_y)
        self.poses = poses
        self.model_name, self.model_params = model, dict(model_params)
        self.light_distance = light_distance_mm
        self.camera_distance = camera_distance_mm
        self.max_theta = max_theta_deg
        self.intensity = intensity if intensity is not None else light_distance_mm**2
        self.noise, self.saturation, self.seed, self.pose_delay = noise, saturation, seed, pose_delay_s
        self.model: BRDFModel | None = None
        self._cache: dict | None = None

    def __getstate__(self) -> dict:
        # The per-pose cache is rebuilt where the poses are read: it never travels with the source.
        return {**self.__dict__, "_cache": None}

    def bind(self, registry) -> None:
        """Called by the runner: resolve the model through the run's registry."""
        self.model = registry.create("brdf-model", self.model_name, self.model_params)
        self._cache = None

    def _bound_model(self) -> BRDFModel:
        """The material's model, which :meth:`bind` resolves (the runner binds every source before reading it)."""
        assert self.model is not None, "synthetic: read before bind() resolved the model"
        return self.model

    def _pose_inputs(self) -> dict:
        """What every pose shares (texel centres, pose positions, flattened ground truth), computed once per process:
        recomputing the maps for every pose was half of ``read_pose``."""
        if self._cache is None:
            self._cache = {
                "p": texel_centres(self.texels, self.size_mm).reshape(-1, 3),
                "light": self.light_positions(),
                "camera": self.camera_positions(),
                "truth": {k: v.reshape(-1, v.shape[-1]) for k, v in self.ground_truth().items()},
            }
        return self._cache

    # -- geometry -----------------------------------------------------------------

    def light_positions(self) -> np.ndarray:
        return fibonacci_hemisphere(self.poses, self.max_theta) * self.light_distance

    def camera_positions(self) -> np.ndarray:
        # A second, rotated spiral so view and light directions decorrelate.
        return fibonacci_hemisphere(self.poses, self.max_theta, offset=2.0)[::-1] * self.camera_distance

    def ground_truth(self) -> dict[str, np.ndarray]:
        """The material's parameter maps, ``name -> (V, U, C)``."""
        n_u, n_v = self.texels
        out = {}
        for k, p in enumerate(self._bound_model().parameters):
            lo, hi = p.typical
            out[p.name] = np.stack([lo + (hi - lo) * pattern(n_u, n_v, k, c) for c in range(p.channels)], axis=-1)
        return out

    # -- capture source protocol ------------------------------------------------------

    def describe(self) -> CaptureDescription:
        n_u, n_v = self.texels
        cams = self.camera_positions()
        Rt = [look_at(c) for c in cams]
        f = n_u / (self.size_mm[0] / self.camera_distance)
        return CaptureDescription(
            height=n_v, width=n_u,
            light_pos=self.light_positions(),
            camera_R=np.stack([R for R, _ in Rt]),
            camera_t=np.stack([t for _, t in Rt]),
            exposure_s=np.full(self.poses, 1.0),
            sample={"size_mm": list(self.size_mm), "fiducials": None},
            camera={"width": n_u, "height": n_v, "K": [[f, 0, n_u / 2], [0, f, n_v / 2], [0, 0, 1]],
                    "dist": [0, 0, 0, 0, 0], "response": "linear", "model": "texel-aligned"},
            light={"type": "point", "intensity": self.intensity},
        )

    def read_pose(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        if self.pose_delay:
            time.sleep(self.pose_delay)
        n_u, n_v = self.texels
        c = self._pose_inputs()
        wi, r = directions_to(c["p"], c["light"][index: index + 1])
        wo, _ = directions_to(c["p"], c["camera"][index: index + 1])
        f = self._bound_model().eval(c["truth"], wi, wo)  # (T, 1, 3)
        cos_i = np.clip(wi[..., 2], 0, None)
        L = f * (self.intensity * cos_i / r**2)[..., None]
        if self.noise:
            rng = np.random.default_rng([self.seed, index])
            L = L * (1 + self.noise * rng.standard_normal(L.shape))
        L = np.clip(L, 0, None)
        valid = np.ones(L.shape[0], bool)
        if self.saturation is not None:
            valid = (L < self.saturation).all(axis=-1)[:, 0]
            L = np.minimum(L, self.saturation)
        return L.reshape(n_v, n_u, 3).astype(np.float32), valid.reshape(n_v, n_u)
