"""Reflectance: radiance -> sampled BRDF, transposed texel-tile-major.

Per texel and pose, from the registered geometry (not per pose: the light
falls off by ≈10 % across a sample, seed 000 §3.7):

    f_r = L · r² / (I · cos θ_i)

with r the texel-to-light distance and I the light's radiant intensity.
Samples lit or seen at grazing angles (cos θ < ``min_cos``), non-finite or
masked by registration are marked invalid and stored as 0, never NaN.

The result is stored with all poses of a texel tile in one chunk because
fitting needs every sample of a texel at once.  The pose-major -> tile-major
transpose is the pipeline's one big shuffle: one task per tile reads that
tile's chunk from every pose-block shard of the stack (zarr sharding, see
``register.pose_block``), so a task holds one tile of all poses, never the
scan, and the graph has one task per tile whatever the number of poses.
"""

from __future__ import annotations

import numpy as np

from ..artifacts import RegisteredStack, SampledReflectance
from ..geometry import directions_to, texel_centres
from ..params import Param
from ..store import texel_tile
from .base import BuildContext, NodeKind, Output, Port, shared


def reflectance_block(radiance: np.ndarray, valid: np.ndarray, light_pos: np.ndarray, camera_pos: np.ndarray,
                      texels: tuple[int, int], size_mm: tuple[float, float], intensity: float, min_cos: float,
                      rows: tuple[int, int] | None = None, cols: tuple[int, int] | None = None) -> np.ndarray:
    """Kernel over a pose block: ``radiance (p, V', U', 3)`` -> ``(p, V', U', 4)`` = f_r RGB + validity.

    ``rows``/``cols`` (``(start, stop)``) place a block that holds only part of
    the texel grid (the default is the whole grid).
    """
    v0, v1 = rows if rows is not None else (0, None)
    u0, u1 = cols if cols is not None else (0, None)
    p = texel_centres(texels, size_mm, v0, v1, u0, u1)  # (V', U', 3)
    wi, r = directions_to(p, light_pos)  # (V, U, p, 3), (V, U, p)
    wo, _ = directions_to(p, camera_pos)
    cos_i = np.moveaxis(wi[..., 2], -1, 0)  # (p, V, U)
    cos_o = np.moveaxis(wo[..., 2], -1, 0)
    r2 = np.moveaxis(r, -1, 0) ** 2
    ok = valid & (cos_i > min_cos) & (cos_o > min_cos)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = radiance * (r2 / (intensity * np.where(ok, cos_i, 1.0)))[..., None]
    ok &= np.isfinite(f).all(axis=-1)
    out = np.empty(radiance.shape[:3] + (4,), np.float32)
    out[..., :3] = np.where(ok[..., None], f, 0.0)
    out[..., 3] = ok
    return out


def _tile(grid: np.ndarray, radiance, valid, light_pos: np.ndarray, camera_pos: np.ndarray, texels, size_mm, intensity,
          min_cos, block_info=None) -> np.ndarray:
    """Kernel: one texel tile -> ``(t, t, P, 4)``, all its poses read from the stack's zarr arrays.

    This is the transpose: the tile's chunk of every pose-block shard is read, and
    nothing else, so a task holds one tile of all poses (never the scan).
    """
    (v0, v1), (u0, u1) = block_info[None]["array-location"][:2]
    out = reflectance_block(radiance[:, v0:v1, u0:u1], valid[:, v0:v1, u0:u1], light_pos, camera_pos, texels, size_mm,
                            intensity, min_cos, (v0, v1), (u0, u1))
    return out.transpose(1, 2, 0, 3)


class Reflectance(NodeKind):
    name = "Reflectance"
    doc = "Convert registered radiance to sampled BRDF values (sr^-1), stored texel-tile-major."
    inputs = (Port("stack", (RegisteredStack,), "registered radiance"),)
    output = SampledReflectance
    params = (
        Param("tile", "int", None, "edge of the texel tile stored per chunk; default picks 32..128 for ~16 MiB chunks (down to 8 past ~1000 poses)",
              bounds=(1, 4096), nullable=True),
        Param("min_cos", "float", 0.02, "samples lit or seen with cos θ below this are invalid (grazing)", bounds=(0.0, 1.0)),
    )

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        stack = ctx.inputs["stack"]
        texels = tuple(stack.attrs["texels"])
        size_mm = tuple(stack.attrs["size_mm"])
        intensity = float(stack.attrs.get("light", {}).get("intensity", 1.0))
        light_pos, camera_pos = stack.read("light_pos"), stack.read("camera_pos")
        P, V, U = stack.zarr_array("valid").shape
        t = texel_tile((V, U), P, channels=4, tile=ctx.params["tile"])
        # One graph key each (O(poses)), not a copy in every tile's task.
        grid = da.zeros((V, U), chunks=t, dtype=np.uint8)
        tiled = da.map_blocks(
            _tile, grid, shared(stack.zarr_array("radiance")), shared(stack.zarr_array("valid")), shared(light_pos),
            shared(camera_pos), texels, size_mm, intensity, ctx.params["min_cos"],
            new_axis=[2, 3], chunks=grid.chunks + ((P,), (4,)), dtype=np.float32, name=f"reflectance-{ctx.node}",
        )  # (V, U, P, 4)
        return Output(
            arrays={
                "f_r": tiled[..., :3],
                "valid": tiled[..., 3] > 0.5,
                "light_pos": da.from_array(light_pos),
                "camera_pos": da.from_array(camera_pos),
            },
            attrs={"texels": list(texels), "size_mm": list(size_mm), "light": stack.attrs.get("light", {}), "tile": t},
            stream=2,  # texel tiles
        )
