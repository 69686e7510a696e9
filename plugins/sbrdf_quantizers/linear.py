"""linear: one texture per model parameter, fixed point or float.

Fixed point (``uint8``, ``uint16``): per channel, the texel value t encodes
x = t · scale + bias, with bias the channel's minimum and scale spanning its
range, so no code is wasted on values the material never takes.  Float
(``float16``, ``float32``): stored as is (scale 1, bias 0); ``float16``
keeps ~3 significant digits and overflows above 65504, so out-of-range
values are clipped rather than turned into infinity.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.types import Encoded

from .declarations import LINEAR


class LinearQuantizer:
    """One texture per model parameter: fixed point with per-channel scale/bias over the data range, or float."""

    params = LINEAR

    def __init__(self, *, dtype: str = "uint8"):
        self.dtype = np.dtype(dtype)

    def encode(self, params, model) -> Encoded:
        enc = Encoded()
        for name, x in params.items():
            if self.dtype.kind == "f":
                info = np.finfo(self.dtype)
                enc.textures[name] = x.clip(float(info.min), float(info.max)).astype(self.dtype)
                enc.scale[name] = np.ones(x.shape[-1])
                enc.bias[name] = np.zeros(x.shape[-1])
                continue
            top = np.iinfo(self.dtype).max
            lo = x.min(axis=(0, 1)).astype(np.float64)
            hi = x.max(axis=(0, 1)).astype(np.float64)
            span = hi - lo
            scale = (span + (span <= 0)) / top  # a constant channel decodes exactly from bias
            enc.textures[name] = ((x - lo) / scale).round().clip(0, top).astype(self.dtype)
            enc.scale[name], enc.bias[name] = scale, lo
        return enc

    def decode(self, textures, scale, bias, model):
        return {name: t.astype(np.float64) * scale[name] + bias[name] for name, t in textures.items()}
