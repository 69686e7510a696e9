"""fixed16: 16-bit fixed point, one texture per parameter, in the form that spends the codes well.

Two choices make 16 bits go much further than a plain linear map
(``linear`` with ``dtype: uint16``) for models whose parameters trade off or
span decades:

- **Logarithmic channels with a floor** for non-negative magnitudes (ρ_d,
  ρ_s: lower bound 0): u = log(x + ε), ε = 10⁻³ × the parameter's typical
  upper value.  Fitted maps have heavy tails (a few texels with ρ_s in the
  hundreds), and a linear channel's step would be set by them: 16 bits over
  [0, 350] sr⁻¹ is 5·10⁻³ sr⁻¹, coarser than half float for every ordinary
  texel.  With the log the step is relative above ε and ≈ ε·step below.
- **Logarithmic channels** for positive parameters declared over more than
  two decades (Lafortune exponent n ∈ [0.1, 2·10⁴], Ward/Cook–Torrance α,
  Phong n): a fixed *relative* step, which is what a lobe's shape is sensitive
  to (x^n changes by n·Δn/n·ln x).

Each channel's scale and bias span the material's own range (minimum to
maximum over the texels), as in ``linear``.  Decoding is ``t · scale + bias``,
then ``exp`` for the logarithmic channels, which the model's declaration
determines, so a TextureSet decodes without the encoder's settings.

``canonical: true`` stores :meth:`BRDFModel.canonical` parameters instead
(Lafortune: C_z = 1, lobes ordered).  Fitted maps are already in that gauge
(the fitters iterate with C_z = 1), where C_z is constant and decodes exactly
from its bias.  It is off by default because moving a C_z ≠ 1 material to the
gauge multiplies ρ_s by C_z^n, which spreads ρ_s over many decades across
texels and wastes a linear channel's codes on the brightest.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.types import Encoded

from .declarations import FIXED16

TOP = 65535
#: Positive parameters whose declared bounds span more than this ratio are stored as logarithms.
LOG_SPAN = 100.0


def log_parameters(model) -> set[str]:
    """Names of the parameters fixed16 stores as logarithms."""
    return {p.name for p in model.parameters
            if p.bounds[0] > 0 and np.isfinite(p.bounds[1]) and p.bounds[1] / p.bounds[0] > LOG_SPAN}


def floor_parameters(model) -> dict[str, float]:
    """Non-negative magnitudes stored as log(x + ε): name -> ε."""
    return {p.name: 1e-3 * float(p.typical[1]) for p in model.parameters
            if p.bounds[0] == 0 and p.typical[1] > 0 and p.name not in log_parameters(model)}


def _canonical_block(packed, model):
    T = packed.shape[0] * packed.shape[1]
    canon = model.canonical(model.unpack(packed.reshape(T, -1).astype(np.float64)))
    return model.pack(canon).reshape(packed.shape)


class Fixed16Quantizer:
    """16-bit fixed point over each channel's range; magnitudes, exponents and widths stored as logarithms."""

    params = FIXED16

    def __init__(self, *, canonical: bool = False):
        self.canonical = canonical

    def encode(self, params, model) -> Encoded:
        import dask.array as da

        names = [p.name for p in model.parameters]
        if self.canonical:
            packed = da.concatenate([da.asarray(params[n]).astype(np.float64) for n in names], axis=-1)
            packed = packed.rechunk(packed.chunks[:2] + (-1,))
            packed = da.map_blocks(_canonical_block, packed, model, dtype=np.float64)
            sl = model.slices()
            params = {n: packed[..., sl[n]] for n in names}
        logs, floors = log_parameters(model), floor_parameters(model)
        enc = Encoded()
        for name in names:
            x = da.asarray(params[name]).astype(np.float64)
            if name in logs:
                lo_b = next(p.bounds[0] for p in model.parameters if p.name == name)
                x = da.log(da.maximum(x, lo_b))
            elif name in floors:
                x = da.log(da.maximum(x, 0.0) + floors[name])
            lo = x.min(axis=(0, 1))
            hi = x.max(axis=(0, 1))
            span = hi - lo
            scale = (span + (span <= 0)) / TOP  # a constant channel decodes exactly from its bias
            enc.textures[name] = ((x - lo) / scale).round().clip(0, TOP).astype(np.uint16)
            enc.scale[name], enc.bias[name] = scale, lo
        return enc

    def decode(self, textures, scale, bias, model):
        logs, floors = log_parameters(model), floor_parameters(model)
        out = {}
        for name, t in textures.items():
            v = t.astype(np.float64) * scale[name] + bias[name]
            if name in logs:
                v = np.exp(v)
            elif name in floors:
                # below ε·10⁻⁶ is log/exp round-off, far under the 16-bit step (≈ ε·span/65535): exactly 0,
                # so a lobe switched off (ρ_s ≈ 0) stays off whatever its C^n
                v = np.exp(v) - floors[name]
                v = np.where(v < 1e-6 * floors[name], 0.0, v)
            out[name] = v
        return out
