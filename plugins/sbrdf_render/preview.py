"""preview: the flat sample as the capture rig would see it, one pixel per texel.

For each texel, ω_i and ω_o point to the light and the eye, and the pixel is
L = f_r(ω_i, ω_o) · I · cos θ_i / r² with the material's own model.  It is the
quickest faithful look at a fitted or quantized material, tile by tile in dask
and therefore at any texel count.

The image is drawn the way the overhead camera sees the sample and the way
``sbrdf plot`` draws its spatial view (``origin="lower"``): u to the right and
v up, so texel row v = 0 is the bottom row of the image (its last array row)
and v = V - 1 the top row (array row 0).
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_core.geometry import tile_directions
from sbrdf_core.types import RenderResult

from .declarations import PREVIEW


def _shade(stacked, model, texels, size_mm, light, eye, intensity, block_info=None):
    (v0, v1), (u0, u1) = block_info[0]["array-location"][:2]
    wi, r, wo = tile_directions(texels, size_mm, (v0, v1), (u0, u1), light, eye)
    f = model.eval(model.unpack(stacked.reshape(wi.shape[0], -1).astype(np.float64)), wi, wo)
    L = f * (intensity * np.clip(wi[..., 2], 0, None) / r**2)[..., None]
    return L.reshape(v1 - v0, u1 - u0, 3).astype(np.float32)


class PreviewRenderer:
    """``preview``: the flat sample under one point light, one pixel per texel (lazy: drawn when the image is written)."""

    params = PREVIEW

    def __init__(self, *, light_pos_mm=[300.0, 0.0, 520.0], camera_pos_mm=[0.0, 0.0, 800.0],  # noqa: B006 (read only)
                 intensity: float | None = None, exposure: float | None = None):
        self.light = np.asarray(light_pos_mm, float)
        self.eye = np.asarray(camera_pos_mm, float)
        self.intensity = intensity if intensity is not None else float(self.light @ self.light)
        self.exposure = exposure

    def render(self, material, prepared: dict | None = None) -> RenderResult:
        import dask.array as da

        if not hasattr(material, "params"):
            raise SbrdfError(f"preview renders fitted or quantized materials; {material.source} is a "
                             f"{material.artifact.kind}: render it with the cpu or gl renderer and a scene")

        model = material.model
        stacked = da.concatenate([da.asarray(material.params[p.name]) for p in model.parameters], axis=-1)
        stacked = stacked.rechunk({2: -1})
        image = da.map_blocks(
            _shade, stacked, model, material.texels, material.size_mm, self.light, self.eye, self.intensity,
            chunks=stacked.chunks[:2] + ((3,),), dtype=np.float32,
        )[::-1]  # image rows run top to bottom: v = V - 1 first, v = 0 at the bottom
        return RenderResult(image, self.exposure, {"light_pos_mm": self.light.tolist(), "camera_pos_mm": self.eye.tolist(),
                                                   "orientation": "v up: array row 0 is texel row V-1, v = 0 at the bottom"})
