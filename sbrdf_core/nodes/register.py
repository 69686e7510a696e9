"""Register: resample every photograph onto the sample's texel grid.

The plugin measures per-pose geometry once (``register``) and resamples one
pose at a time inside dask tasks (``resample``).  Rejected poses are dropped
from the stack and listed, with their reasons, in the artifact.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..artifacts import CaptureSet, RegisteredStack
from ..store import texel_tile
from .base import BuildContext, NodeKind, Output, Port


@dataclass
class Registration:
    """Geometry of the accepted poses, as measured by a registration plugin."""

    texels: tuple[int, int]  # (U, V)
    size_mm: tuple[float, float]
    pose_ids: np.ndarray  # (P',) accepted capture pose indices
    light_pos: np.ndarray  # (P', 3)
    camera_pos: np.ndarray  # (P', 3)
    homography: np.ndarray  # (P', 3, 3)
    rms_mm: np.ndarray  # (P',)
    rejected: list[dict] = field(default_factory=list)  # [{"pose": i, "reason": "..."}]
    extra: dict = field(default_factory=dict)


def _resample_block(images: np.ndarray, valid: np.ndarray, plugin, registration: Registration, block_info=None) -> np.ndarray:
    """Kernel: one accepted pose -> ``(1, V, U, 4)`` texel radiance + validity."""
    i = block_info[0]["chunk-location"][0]
    texels, ok = plugin.resample(images[0], valid[0, ..., 0], int(registration.pose_ids[i]), registration)
    U, V = registration.texels
    out = np.zeros((1, V, U, 4), np.float32)
    out[0, ..., :3] = texels
    out[0, ..., 3] = ok
    return out


class Register(NodeKind):
    name = "Register"
    doc = "Resample each pose onto the texel grid; measure per-pose geometry; reject bad poses."
    inputs = (Port("capture", (CaptureSet,), "the photographs"),)
    output = RegisteredStack
    plugin_category = "registration"

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        capture = ctx.inputs["capture"]
        reg: Registration = ctx.plugin.register(capture)
        U, V = reg.texels
        ids = np.asarray(reg.pose_ids, dtype=np.int64)
        images = capture.array("images")[ids].rechunk({0: 1})
        valid = capture.array("valid")[ids].rechunk({0: 1})[..., None]  # align dims with images
        packed = da.map_blocks(
            _resample_block, images, valid, ctx.plugin, reg,
            chunks=((1,) * len(ids), (V,), (U,), (4,)), dtype=np.float32,
            name=f"register-resample-{ctx.node}",
        )
        small = lambda a: da.from_array(np.asarray(a))  # noqa: E731
        # Stored one pose per chunk but split into the texel tiles Reflectance stores
        # all poses of: its pose-major -> tile-major transpose then reads whole chunks,
        # each exactly once, and holds one tile of all poses at a time (never the scan).
        t = texel_tile((V, U), len(ids), channels=4)
        return Output(
            arrays={
                "radiance": packed[..., :3],
                "valid": packed[..., 3] > 0.5,
                "pose_ids": small(ids),
                "light_pos": small(np.asarray(reg.light_pos, float)),
                "camera_pos": small(np.asarray(reg.camera_pos, float)),
                "homography": small(np.asarray(reg.homography, float)),
                "rms_mm": small(np.asarray(reg.rms_mm, float)),
            },
            chunks={"radiance": (1, t, t, 3), "valid": (1, t, t)},
            attrs={
                "texels": [int(U), int(V)],
                "size_mm": [float(s) for s in reg.size_mm],
                "light": capture.attrs.get("light", {}),
                "rejected": reg.rejected,
                "registration": reg.extra,
            },
        )
