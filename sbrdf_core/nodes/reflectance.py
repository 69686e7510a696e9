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

import functools

import numpy as np

from ..artifacts import RegisteredStack, SampledReflectance
from ..channels import all_finite
from ..geometry import directions_to, texel_centres
from ..params import Param
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
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # finite as stored (float32): a sample beyond float32's range is invalid, not an inf marked valid
        f = (radiance * (r2 / (intensity * np.where(ok, cos_i, 1.0)))[..., None]).astype(np.float32)
    ok &= all_finite(f)
    out = np.empty(radiance.shape[:3] + (4,), np.float32)
    out[..., :3] = np.where(ok[..., None], f, np.float32(0.0))
    out[..., 3] = ok
    return out


@functools.cache
def _fused():
    """The compiled kernel of :func:`reflectance_tile` (numba, cached on disk: compiled once per install)."""
    import numba

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def kernel(radiance, valid, x, y, light_pos, camera_pos, intensity, min_cos, out):  # pragma: no cover (compiled)
        P, V, U = valid.shape
        for v in range(V):
            for u in range(U):
                for p in range(P):
                    # directions_to's arithmetic, in its order (same bits): d = target − point, r = √(d·d).
                    dx, dy, dz = light_pos[p, 0] - x[u], light_pos[p, 1] - y[v], light_pos[p, 2]
                    r = np.sqrt(dx * dx + dy * dy + dz * dz)
                    cos_i = dz / r if r != 0 else 1.0
                    ex, ey, ez = camera_pos[p, 0] - x[u], camera_pos[p, 1] - y[v], camera_pos[p, 2]
                    ro = np.sqrt(ex * ex + ey * ey + ez * ez)
                    cos_o = ez / ro if ro != 0 else 1.0
                    ok = valid[p, v, u] and cos_i > min_cos and cos_o > min_cos
                    scale = r ** 2 / (intensity * (cos_i if ok else 1.0))
                    f0 = np.float32(np.float64(radiance[p, v, u, 0]) * scale)  # finite as stored
                    f1 = np.float32(np.float64(radiance[p, v, u, 1]) * scale)
                    f2 = np.float32(np.float64(radiance[p, v, u, 2]) * scale)
                    ok = ok and np.isfinite(f0) and np.isfinite(f1) and np.isfinite(f2)
                    o = out[v, u, p]
                    if ok:
                        o[0], o[1], o[2], o[3] = f0, f1, f2, 1.0
                    else:
                        o[0], o[1], o[2], o[3] = 0.0, 0.0, 0.0, 0.0

    return kernel


def reflectance_tile(radiance: np.ndarray, valid: np.ndarray, light_pos: np.ndarray, camera_pos: np.ndarray,
                     texels: tuple[int, int], size_mm: tuple[float, float], intensity: float, min_cos: float,
                     rows: tuple[int, int], cols: tuple[int, int]) -> np.ndarray:
    """:func:`reflectance_block`'s values, transposed: ``(p, V', U', 3)`` -> ``(V', U', p, 4)``, in one pass.

    One compiled loop computes each sample's geometry, f_r and validity and
    writes it texel-major: no (p, V', U') float64 temporaries (ten passes over
    them were three quarters of the node's time) and no separate transpose.
    The same bits as :func:`reflectance_block` (tests/core/test_reflectance_kernel.py).
    """
    (v0, v1), (u0, u1) = rows, cols
    p = texel_centres(texels, size_mm, v0, v1, u0, u1)
    out = np.empty((v1 - v0, u1 - u0, radiance.shape[0], 4), np.float32)
    _fused()(np.ascontiguousarray(radiance, np.float32), np.ascontiguousarray(valid, bool),
             np.ascontiguousarray(p[0, :, 0]), np.ascontiguousarray(p[:, 0, 1]),
             np.ascontiguousarray(light_pos, np.float64), np.ascontiguousarray(camera_pos, np.float64),
             float(intensity), float(min_cos), out)
    return out


#: Samples (poses × texels) from which a node uses the compiled kernel: below, loading it (numba, about half
#: a second and 80 MB per process) costs more than the NumPy kernel does.
FUSED_MIN_SAMPLES = 2**21


def _tile(grid: np.ndarray, radiance, valid, light_pos: np.ndarray, camera_pos: np.ndarray, texels, size_mm, intensity,
          min_cos, fused: bool = True, block_info=None) -> np.ndarray:
    """Kernel: one texel tile -> ``(t, t, P, 4)``, all its poses read from the stack's zarr arrays.

    This is the transpose: the tile's chunk of every pose-block shard is read, and
    nothing else, so a task holds one tile of all poses (never the scan).
    """
    (v0, v1), (u0, u1) = block_info[None]["array-location"][:2]
    kernel = reflectance_tile if fused else _unfused
    return kernel(radiance[:, v0:v1, u0:u1], valid[:, v0:v1, u0:u1], light_pos, camera_pos, texels, size_mm,
                  intensity, min_cos, (v0, v1), (u0, u1))


def _unfused(*args) -> np.ndarray:
    """:func:`reflectance_block`, transposed to ``(V', U', p, 4)``: the same bits as :func:`reflectance_tile`."""
    return reflectance_block(*args).transpose(1, 2, 0, 3)


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
        from ..store import texel_tile

        t = texel_tile((V, U), P, channels=4, tile=ctx.params["tile"])
        # One graph key each (O(poses)), not a copy in every tile's task.
        grid = da.zeros((V, U), chunks=t, dtype=np.uint8)
        tiled = da.map_blocks(
            _tile, grid, shared(stack.zarr_array("radiance")), shared(stack.zarr_array("valid")), shared(light_pos),
            shared(camera_pos), texels, size_mm, intensity, ctx.params["min_cos"], P * V * U >= FUSED_MIN_SAMPLES,
            new_axis=[2, 3], chunks=grid.chunks + ((P,), (4,)), dtype=np.float32, name=ctx.key("reflectance"),
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
