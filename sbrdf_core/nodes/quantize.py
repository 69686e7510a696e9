"""Quantize: parameter maps -> textures with the scale/bias that decode them.

Quantizer protocol:

- ``encode(params, model) -> Encoded``: lazy textures (``(V, U, K)`` dask
  arrays) plus per-channel ``scale`` and ``bias`` (``(K,)``, may be lazy);
- ``decode(textures, scale, bias, model) -> params``: the inverse, written
  with elementwise array operations so it works on NumPy blocks and on dask
  arrays alike.

The node measures what quantizing cost, identically for every layout: per
texel, the RMS difference in sr⁻¹ between the model with original and with
decoded parameters over a fixed set of direction pairs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..artifacts import ParamMaps, TextureSet
from ..geometry import fibonacci_hemisphere
from .base import BuildContext, NodeKind, Output, Port


@dataclass
class Encoded:
    textures: dict = field(default_factory=dict)
    scale: dict = field(default_factory=dict)
    bias: dict = field(default_factory=dict)


def error_directions(n: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Fixed direction pairs for error measurement: ``(1, n², 3)`` each (all wi × all wo)."""
    d = fibonacci_hemisphere(n, max_theta_deg=85.0)
    wi = np.repeat(d, n, axis=0)[None]
    wo = np.tile(d, (n, 1))[None]
    return wi, wo


def _error_tile(original, decoded, model, n_dirs):
    v, u, K = original.shape
    wi, wo = error_directions(n_dirs)
    T = v * u
    wi, wo = np.broadcast_to(wi, (T,) + wi.shape[1:]), np.broadcast_to(wo, (T,) + wo.shape[1:])
    a = model.eval(model.unpack(original.reshape(T, K).astype(np.float64)), wi, wo)
    b = model.eval(model.unpack(decoded.reshape(T, K).astype(np.float64)), wi, wo)
    return np.sqrt(np.mean((a - b) ** 2, axis=(1, 2))).reshape(v, u).astype(np.float32)


def model_of(ctx: BuildContext, artifact):
    """The BRDF model an artifact was fitted with, from its attributes."""
    return ctx.registry.create("brdf-model", artifact.attrs["model"], dict(artifact.attrs.get("model_config", {})))


class Quantize(NodeKind):
    name = "Quantize"
    doc = "Encode parameter maps as textures; report the error quantizing added and bytes per texel."
    inputs = (Port("params", (ParamMaps,), "fitted parameter maps"),)
    output = TextureSet
    plugin_category = "quantizer"

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        pm = ctx.inputs["params"]
        model = model_of(ctx, pm)
        params = {p.name: pm.array(f"params/{p.name}") for p in model.parameters}
        enc: Encoded = ctx.plugin.encode(params, model)
        decoded = ctx.plugin.decode(enc.textures, enc.scale, enc.bias, model)
        original = da.concatenate([params[p.name] for p in model.parameters], axis=-1)
        restored = da.concatenate([da.asarray(decoded[p.name]).astype(np.float32) for p in model.parameters], axis=-1)
        restored = restored.rechunk(original.chunks)
        error = da.map_blocks(_error_tile, original, restored, model, 16, drop_axis=[2], dtype=np.float32,
                              name=f"quantize-error-{ctx.node}")
        arrays = {f"textures/{k}": t for k, t in enc.textures.items()}
        arrays.update({f"scale/{k}": da.asarray(s, dtype=np.float64) for k, s in enc.scale.items()})
        arrays.update({f"bias/{k}": da.asarray(b, dtype=np.float64) for k, b in enc.bias.items()})
        arrays["error"] = error
        bytes_per_texel = int(sum(np.dtype(t.dtype).itemsize * t.shape[-1] for t in enc.textures.values()))

        def finalize(art):
            e = art.read("error")
            return {"added_rms": float(np.sqrt(np.mean(e.astype(np.float64) ** 2))), "added_max": float(e.max())}

        return Output(
            arrays=arrays,
            attrs={
                "quantizer": ctx.spec.name,
                "model": pm.attrs["model"],
                "model_config": pm.attrs.get("model_config", {}),
                "parameters": pm.attrs.get("parameters", []),
                "texels": pm.attrs.get("texels"),
                "size_mm": pm.attrs.get("size_mm"),
                "bytes_per_texel": bytes_per_texel,
            },
            finalize=finalize,
        )
