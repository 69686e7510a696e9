"""Quantize: parameter maps -> textures with the scale/bias that decode them.

Quantizer protocol:

- ``encode(params, model) -> Encoded``: lazy textures (``(V, U, K)`` dask
  arrays) plus per-channel ``scale`` and ``bias`` (``(K,)``, may be lazy);
- ``decode(textures, scale, bias, model) -> params``: the inverse, written
  with elementwise array operations so it works on NumPy blocks and on dask
  arrays alike.

Optional, for layouts that are more than arrays:

- ``write_files(art, textures, scale, bias, model) -> dict``: called once
  every chunk is written, with the (still incomplete) artifact and the
  textures read back as NumPy; writes files
  beside the arrays (an EXR, a JSON description, PNGs) and returns attributes
  to record (``{"files": [...]}``);
- ``bytes_per_texel(textures) -> float``: when the stored arrays are not what
  a renderer would hold (a palette index plus a shared palette);
- ``prepare(params, model) -> {name: dask collection}``: global data the
  encoding needs concrete (a palette's clustering sees every texel).  The
  runner computes it before ``build`` on the run's scheduler, with progress,
  and ``encode`` then gets ``prepared=`` the results: building never computes.

The node measures what quantizing cost, identically for every layout: per
texel, the RMS difference in sr⁻¹ between the model with original and with
decoded parameters over a fixed set of direction pairs (``error``), and, when
the node is also given the SampledReflectance the parameters were fitted to
(optional input ``samples``), over each texel's own valid sampled directions
(``error_own``): the uniform set weighs grazing pairs the capture never saw,
the own set weighs what was measured.
"""

from __future__ import annotations

import numpy as np

from ..artifacts import ParamMaps, SampledReflectance, TextureSet
from ..contracts import BRDFModel, Quantizer, optional
from ..geometry import fibonacci_hemisphere, tile_directions
from ..types import Encoded
from .base import BuildContext, NodeKind, Output, Port


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


def _own_tile(stacked, K, model, texels, size_mm, light_pos, camera_pos, block_info=None):
    """Kernel: ``stacked`` = original (K) | decoded (K) | valid (P) along the last axis, one texel tile."""
    (v0, v1), (u0, u1) = block_info[0]["array-location"][:2]
    return own_error(stacked[..., :K], stacked[..., K:2 * K], stacked[..., 2 * K:] > 0.5, model, texels, size_mm,
                     light_pos, camera_pos, (v0, v1), (u0, u1))


def own_error(original, decoded, valid, model, texels, size_mm, light_pos, camera_pos, rows, cols):
    """Per-texel RMS (sr⁻¹) of original − decoded over the texels' own valid sampled directions.

    ``original``, ``decoded`` are packed ``(v, u, K)`` maps of texel rows ``rows`` and columns ``cols``
    of a ``texels`` = (U, V) grid; ``valid`` is ``(v, u, P)``.  A texel with no valid sample gets 0.
    """
    v0, v1 = rows
    u0, u1 = cols
    v, u, K = original.shape
    wi, _, wo = tile_directions(texels, size_mm, (v0, v1), (u0, u1), light_pos, camera_pos)
    a = model.eval(model.unpack(original.reshape(-1, K).astype(np.float64)), wi, wo)
    b = model.eval(model.unpack(decoded.reshape(-1, K).astype(np.float64)), wi, wo)
    w = valid.reshape(v * u, -1)[..., None].astype(np.float64)
    n = np.maximum(w.sum(axis=(1, 2)) * a.shape[-1], 1.0)
    return np.sqrt(((a - b) ** 2 * w).sum(axis=(1, 2)) / n).reshape(v, u).astype(np.float32)


def decode_texture_set(art, registry, model=None) -> dict[str, np.ndarray]:
    """A TextureSet read back and decoded to parameter maps ``name -> (V, U, C)`` (NumPy)."""
    quantizer = registry.create("quantizer", art.attrs["quantizer"], {})
    if model is None:
        model = registry.create("brdf-model", art.attrs["model"], dict(art.attrs.get("model_config", {})))
    names = sorted({n.split("/", 1)[1] for n in art.names() if n.startswith("textures/")})
    out = quantizer.decode({n: art.read(f"textures/{n}") for n in names}, {n: art.read(f"scale/{n}") for n in names},
                           {n: art.read(f"bias/{n}") for n in names}, model)
    return {p.name: np.asarray(out[p.name]) for p in model.parameters}


def model_of(ctx: BuildContext, artifact) -> BRDFModel:
    """The BRDF model an artifact was fitted with, from its attributes."""
    return ctx.plugins().create("brdf-model", artifact.attrs["model"], dict(artifact.attrs.get("model_config", {})))


class Quantize(NodeKind):
    name = "Quantize"
    doc = "Encode parameter maps as textures; report the error quantizing added and bytes per texel."
    inputs = (Port("params", (ParamMaps,), "fitted parameter maps"),
              Port("samples", (SampledReflectance,), "the samples they were fitted to: error over their own directions",
                   optional=True))
    output = TextureSet
    plugin_category = "quantizer"

    @classmethod
    def prepare(cls, ctx: BuildContext) -> dict:
        """The quantizer's optional ``prepare(params, model)``: what its ``encode`` needs computed."""
        prepare = optional(ctx.plugin, "prepare", "quantizer")
        if not callable(prepare):
            return {}
        pm = ctx.inputs["params"]
        model = model_of(ctx, pm)
        return prepare({p.name: pm.array(f"params/{p.name}") for p in model.parameters}, model)

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        quantizer: Quantizer = ctx.plugin
        pm = ctx.inputs["params"]
        model = model_of(ctx, pm)
        params = {p.name: pm.array(f"params/{p.name}") for p in model.parameters}
        if callable(optional(quantizer, "prepare", "quantizer")):
            prepared = ctx.prepared
            if prepared is None:  # built outside a runner (a test, a notebook): compute it here
                import dask

                wanted = cls.prepare(ctx)
                prepared = dict(zip(wanted, dask.compute(*wanted.values())))
            enc: Encoded = quantizer.encode(params, model, prepared=prepared)
        else:
            enc = quantizer.encode(params, model)
        decoded = quantizer.decode(enc.textures, enc.scale, enc.bias, model)
        original = da.concatenate([params[p.name] for p in model.parameters], axis=-1)
        restored = da.concatenate([da.asarray(decoded[p.name]).astype(np.float32) for p in model.parameters], axis=-1)
        restored = restored.rechunk(original.chunks)
        error = da.map_blocks(_error_tile, original, restored, model, 16, drop_axis=[2], dtype=np.float32,
                              name=ctx.key("quantize-error"))
        arrays = {f"textures/{k}": t for k, t in enc.textures.items()}
        arrays.update({f"scale/{k}": da.asarray(s, dtype=np.float64) for k, s in enc.scale.items()})
        arrays.update({f"bias/{k}": da.asarray(b, dtype=np.float64) for k, b in enc.bias.items()})
        arrays["error"] = error
        samples = ctx.inputs.get("samples")
        if samples is not None:
            valid = samples.array("valid")
            sa = samples.attrs
            if tuple(valid.shape[:2]) != tuple(original.shape[:2]):
                raise ValueError(f"Quantize {ctx.node!r}: samples have {valid.shape[1]}×{valid.shape[0]} texels, "
                                 f"params {original.shape[1]}×{original.shape[0]}: give the samples they were fitted to")
            tile = valid.chunks[0], valid.chunks[1]
            K = original.shape[-1]
            stacked = da.concatenate([original.astype(np.float32).rechunk(tile + (-1,)),
                                      restored.rechunk(tile + (-1,)), valid.astype(np.float32)], axis=2)
            own = da.map_blocks(
                _own_tile, stacked.rechunk(tile + (-1,)), K, model, tuple(sa["texels"]), tuple(sa["size_mm"]),
                samples.read("light_pos"), samples.read("camera_pos"), drop_axis=[2], dtype=np.float32,
                name=ctx.key("quantize-error-own"))
            arrays["error_own"] = own.rechunk(original.chunks[:2])
        sized = optional(ctx.plugin, "bytes_per_texel", "quantizer")
        bytes_per_texel = (sized(enc.textures) if callable(sized) else
                           int(sum(np.dtype(t.dtype).itemsize * t.shape[-1] for t in enc.textures.values())))
        write_files = optional(ctx.plugin, "write_files", "quantizer")

        def finalize(art):
            rms = lambda e: float(np.sqrt(np.mean(e.astype(np.float64) ** 2)))  # noqa: E731
            e = art.read("error")
            out = {"added_rms": rms(e), "added_max": float(e.max())}
            if samples is not None:
                out["added_rms_own"] = rms(art.read("error_own"))
            if callable(write_files):
                names = list(enc.textures)
                out.update(write_files(art, {k: art.read(f"textures/{k}") for k in names},
                                       {k: art.read(f"scale/{k}") for k in names},
                                       {k: art.read(f"bias/{k}") for k in names}, model) or {})
            return out

        return Output(
            arrays=arrays,
            attrs={
                "quantizer": ctx.plugin_name,
                "model": pm.attrs["model"],
                "model_config": pm.attrs.get("model_config", {}),
                "parameters": pm.attrs.get("parameters", []),
                "texels": pm.attrs.get("texels"),
                "size_mm": pm.attrs.get("size_mm"),
                "bytes_per_texel": bytes_per_texel,
            },
            finalize=finalize,
        )
