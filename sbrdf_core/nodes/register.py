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


def pose_block(texels_vu: tuple[int, int], poses: int, tile: int, target_bytes: int = 1 << 20,
               gather_bytes: int = 64 << 20) -> int:
    """Poses per stored stack chunk: enough for ~``target_bytes`` chunks, at most ``gather_bytes`` of poses per write.

    A texel tile of one pose is small (32² texels: 12 KB) and every chunk costs a
    file, a done marker and a task or more; at a few hundred poses that per-chunk
    cost, not the pixels, dominates Register and Reflectance (measured: 27 poses
    at 32² tiles, one pose per chunk, were 4–7× slower than at 128² tiles).  One
    write gathers ``k`` resampled poses (``V·U·16`` bytes each), so ``k`` is capped
    by ``gather_bytes``: memory stays bounded whatever the number of poses.
    """
    V, U = texels_vu
    k = min(target_bytes // max(tile * tile * 3 * 4, 1), gather_bytes // max(V * U * 16, 1))
    return int(max(1, min(poses, k)))


class Register(NodeKind):
    name = "Register"
    doc = "Resample each pose onto the texel grid; measure per-pose geometry; reject bad poses."
    inputs = (Port("capture", (CaptureSet,), "the photographs"),)
    output = RegisteredStack
    plugin_category = "registration"

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da
        from dask import delayed

        capture = ctx.inputs["capture"]
        reg: Registration = ctx.plugin.register(capture)
        U, V = reg.texels
        ids = np.asarray(reg.pose_ids, dtype=np.int64)
        images = capture.array("images")[ids].rechunk({0: 1})
        valid = capture.array("valid")[ids].rechunk({0: 1})[..., None]  # align dims with images
        # The plugin and the Registration (per-pose geometry, O(poses)) are one graph key
        # each, fetched once per worker; as plain arguments every pose's task would carry
        # a copy, and a worker's queued tasks would hold O(poses²) bytes.
        shared = lambda obj: delayed(obj, pure=True, traverse=False)  # noqa: E731
        packed = da.map_blocks(
            _resample_block, images, valid, shared(ctx.plugin), shared(reg),
            chunks=((1,) * len(ids), (V,), (U,), (4,)), dtype=np.float32,
            name=f"register-resample-{ctx.node}",
        )
        small = lambda a: da.from_array(np.asarray(a))  # noqa: E731
        # Stored pose-major in blocks of k poses (pose_block), split into the texel tiles
        # Reflectance stores all poses of: its pose-major -> tile-major transpose then
        # reads whole chunks, each exactly once, and holds one tile of all poses at a
        # time (never the scan).
        t = texel_tile((V, U), len(ids), channels=4)
        k = pose_block((V, U), len(ids), t)
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
            chunks={"radiance": (k, t, t, 3), "valid": (k, t, t)},
            streamed=True,  # pose blocks share no work: the runner submits a few at a time
            attrs={
                "texels": [int(U), int(V)],
                "size_mm": [float(s) for s in reg.size_mm],
                "light": capture.attrs.get("light", {}),
                "rejected": reg.rejected,
                "registration": reg.extra,
            },
        )
