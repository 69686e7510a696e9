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

import numpy as np

from sbrdf_core.geometry import directions_to, fibonacci_hemisphere, look_at, texel_centres
from sbrdf_core.nodes.capture import CaptureDescription


def pattern(n_u: int, n_v: int, index: int, channel: int) -> np.ndarray:
    """Smooth waves plus a 4×4 checker, in [0, 1], different per parameter and channel."""
    u = (np.arange(n_u) + 0.5) / n_u
    v = (np.arange(n_v) + 0.5) / n_v
    uu, vv = np.meshgrid(u, v)
    waves = 0.5 + 0.25 * np.sin(2 * np.pi * ((1 + index) * uu + channel / 3)) * np.cos(2 * np.pi * (1 + channel) * vv)
    checker = ((np.floor(uu * 4) + np.floor(vv * 4)) % 2) * 0.5 - 0.25
    return np.clip(waves + 0.8 * checker * (0.5 if index else 1.0), 0.0, 1.0)


class SyntheticCapture:
    """Simulated gonioreflectometer capture of a procedural material."""

    def __init__(self, texels, size_mm, poses, model, model_params, light_distance_mm, camera_distance_mm,
                 max_theta_deg, intensity, noise, saturation, seed, pose_delay_s):
        self.texels = tuple(texels)
        self.size_mm = tuple(size_mm)
        self.poses = poses
        self.model_name, self.model_params = model, dict(model_params)
        self.light_distance = light_distance_mm
        self.camera_distance = camera_distance_mm
        self.max_theta = max_theta_deg
        self.intensity = intensity if intensity is not None else light_distance_mm**2
        self.noise, self.saturation, self.seed, self.pose_delay = noise, saturation, seed, pose_delay_s
        self.model = None

    def bind(self, registry) -> None:
        """Called by the runner: resolve the model through the run's registry."""
        self.model = registry.create("brdf-model", self.model_name, self.model_params)

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
        for k, p in enumerate(self.model.parameters):
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
        p = texel_centres(self.texels, self.size_mm).reshape(-1, 1, 3)
        wi, r = directions_to(p[:, 0], self.light_positions()[index: index + 1])
        wo, _ = directions_to(p[:, 0], self.camera_positions()[index: index + 1])
        truth = {k: v.reshape(-1, v.shape[-1]) for k, v in self.ground_truth().items()}
        f = self.model.eval(truth, wi, wo)  # (T, 1, 3)
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
