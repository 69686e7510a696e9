"""Register: resample every photograph onto the sample's texel grid.

The plugin measures per-pose geometry once (``register``) and resamples one
pose at a time inside dask tasks (``resample``).  Rejected poses are dropped
from the stack and listed, with their reasons, in the artifact.

A plugin whose measurement needs the photographs (fiducial detection) returns
that work lazily from its optional ``prepare(capture)`` (name -> dask
collection); the runner computes it with the run's scheduler and progress bar,
and ``register(capture, prepared=...)`` receives the results.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import contracts
from ..artifacts import CaptureSet, RegisteredStack
from ..contracts import optional
from ..store import texel_tile
from ..types import Registration
from .base import BuildContext, NodeKind, Output, Port, shared


def _resample_poses(index: np.ndarray, images, valid, plugin, registration: Registration) -> np.ndarray:
    """Kernel: one pose block -> ``(k, V, U, 4)`` texel radiance + validity.

    ``index`` holds the block's positions in the accepted poses; each photograph
    is read from the capture's zarr arrays and resampled in turn, so a task holds
    one photograph and its block's output, never the block's photographs.
    """
    U, V = registration.texels
    out = np.zeros((len(index), V, U, 4), np.float32)
    for j, k in enumerate(index):
        pose = int(registration.pose_ids[k])
        texels, ok = plugin.resample(images[pose], valid[pose], pose, registration)
        out[j, ..., :3] = texels
        out[j, ..., 3] = ok
    return out


def pose_block(texels_vu: tuple[int, int], poses: int, gather_bytes: int = 32 << 20, min_blocks: int = 8) -> int:
    """Poses per Register task and per stored shard: at most ``gather_bytes`` of resampled poses.

    One task resamples ``k`` poses into ``(k, V, U, 4)`` float32 (``V·U·16`` bytes
    a pose) and writes them as one zarr shard of texel-tile chunks, so memory
    per task is bounded whatever the number of poses, and the graph has one task
    per block, not per pose and tile (per pose and tile, a scan of thousands of
    poses would be tens of thousands of tasks, held in the client).  At least ``min_blocks``
    blocks keep every core busy on small scans.
    """
    V, U = texels_vu
    k = min(gather_bytes // max(V * U * 16, 1), poses // min_blocks)
    return int(max(1, min(poses, k)))


class Register(NodeKind):
    name = "Register"
    doc = "Resample each pose onto the texel grid; measure per-pose geometry; reject bad poses."
    inputs = (Port("capture", (CaptureSet,), "the photographs"),)
    output = RegisteredStack
    plugin_category = "registration"

    @classmethod
    def prepare(cls, ctx: BuildContext) -> dict[str, Any]:
        prepare = optional(ctx.plugin, "prepare", "registration")
        return dict(prepare(ctx.inputs["capture"])) if prepare is not None else {}

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        capture = ctx.inputs["capture"]
        plugin: contracts.Registration = ctx.plugin
        if optional(plugin, "prepare", "registration") is not None:
            reg: Registration = plugin.register(capture, prepared=ctx.prepared or {})
        else:
            reg = plugin.register(capture)
        U, V = reg.texels
        ids = np.asarray(reg.pose_ids, dtype=np.int64)
        # The plugin, the Registration (per-pose geometry, O(poses)) and the capture's
        # arrays are one graph key each (``shared``), fetched once per worker.
        k = pose_block((V, U), len(ids))
        index = da.arange(len(ids), chunks=k)
        packed = da.map_blocks(
            _resample_poses, index, shared(capture.zarr_array("images")),
            shared(capture.zarr_array("valid")), shared(ctx.plugin), shared(reg),
            new_axis=[1, 2, 3], chunks=(index.chunks[0], (V,), (U,), (4,)),
            dtype=np.float32, name=ctx.key("register-resample"),
        )
        small = lambda a: da.from_array(np.asarray(a))  # noqa: E731
        # Stored pose-major, one shard per pose block (one task writes it whole),
        # made of the texel-tile chunks Reflectance stores all poses of: its
        # pose-major -> tile-major transpose reads one tile of every shard at a time.
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
                **{f"registration/{name}": small(a) for name, a in reg.per_pose.items()},
            },
            chunks={"radiance": (k, V, U, 3), "valid": (k, V, U)},
            inner_chunks={"radiance": (k, t, t, 3), "valid": (k, t, t)},
            attrs={
                "texels": [int(U), int(V)],
                "size_mm": [float(s) for s in reg.size_mm],
                "light": capture.attrs.get("light", {}),
                "rejected": reg.rejected,
                "registration": reg.extra,
            },
            stream=1,  # pose blocks
        )
