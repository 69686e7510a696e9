"""texel-aligned: registration for captures whose pixels already are texels.

Simulators (``synthetic``) render straight onto the texel grid, so there is
nothing to detect or resample: the nominal camera pose is exact, the
homography maps texel centres to pixel centres, and the residual is zero.
Refuses captures that are not texel-aligned, so a real photograph is never
silently treated as registered.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_core.geometry import camera_centre
from sbrdf_core.types import Registration

from .declarations import TEXEL_ALIGNED


class TexelAligned:
    """Register plugin ``texel-aligned`` (see the module docstring)."""

    params = TEXEL_ALIGNED

    def __init__(self, *, max_rms_mm: float = 0.5):
        self.max_rms_mm = max_rms_mm

    def register(self, capture) -> Registration:
        cam = capture.attrs.get("camera", {})
        if cam.get("model") != "texel-aligned":
            raise SbrdfError(
                f"capture {capture.url} holds ordinary photographs (camera model {cam.get('model', 'pinhole')!r}); "
                "texel-aligned registration only accepts simulated texel-aligned captures; use a fiducial registration"
            )
        U, V = int(cam["width"]), int(cam["height"])
        sx, sy = capture.attrs["sample"]["size_mm"]
        P = capture.zarr_array("light_pos").shape[0]
        # mm on the sample plane (origin at the centre) -> pixel coordinates.
        H = np.array([[U / sx, 0, U / 2], [0, V / sy, V / 2], [0, 0, 1.0]])
        return Registration(
            texels=(U, V),
            size_mm=(sx, sy),
            pose_ids=np.arange(P),
            light_pos=capture.read("light_pos"),
            camera_pos=camera_centre(capture.read("camera_R"), capture.read("camera_t")),
            homography=np.broadcast_to(H, (P, 3, 3)).copy(),
            rms_mm=np.zeros(P),
        )

    def resample(self, image, valid, pose, registration):
        return image, valid
