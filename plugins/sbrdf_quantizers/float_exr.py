"""float-exr: float32 or half-float parameter textures, plus one multi-channel EXR per material.

The interchange layout (seed 000 notes §16): every parameter of the material
in one OpenEXR file, ``material.exr``, channels named ``<parameter>.R/.G/.B``
for colour parameters (``rho_d.R``, ``rho_s_1.G``) and ``<parameter>`` for
scalars (``c_xy_1``, ``exponent_1``), each at the layout's precision, beside
``material.json`` describing the channels, units and the colour space (the
same JSON is in the EXR header as the ``sbrdf`` attribute, so the file is
self-describing on its own).  :func:`read_material` decodes either back to
parameter maps.

float32 is exact.  float16 keeps 11 significant bits (relative error ≤ 2⁻¹¹)
and overflows above 65504, so values beyond are clipped rather than turned
into infinity; exponents up to 2·10⁴ and ρ_s up to 10⁶ sr⁻¹ are declared,
so a float16 map of an extreme lobe clips ρ_s.  What that costs in sr⁻¹ is
measured by the Quantize node like every other layout.
"""

from __future__ import annotations

import json

import numpy as np

from sbrdf_core.brdf import LUMINANCE_WEIGHTS
from sbrdf_core.io import read_exr_channels, write_exr_channels
from sbrdf_core.store import join
from sbrdf_core.types import Encoded

from .declarations import FLOAT_EXR

FORMAT = "sbrdf-material/1"
RGB = "RGB"


def channel_names(parameters) -> list[tuple[str, str, int]]:
    """``(exr channel, parameter, component)`` for every channel of a model's declared parameters."""
    out = []
    for p in parameters:
        name, channels = (p.name, p.channels) if not isinstance(p, dict) else (p["name"], p["channels"])
        if channels == 1:
            out.append((name, name, 0))
        elif channels == 3:
            out += [(f"{name}.{c}", name, k) for k, c in enumerate(RGB)]
        else:
            out += [(f"{name}.{k}", name, k) for k in range(channels)]
    return out


def describe_material(model, model_config: dict, dtype: np.dtype, texels, colour_space: str, extra=None) -> dict:
    """The JSON description: format, model, channels (with units and storage type), colour space."""
    units = {p.name: p.unit for p in model.parameters}
    return {
        "format": FORMAT,
        "model": model.name,
        "model_config": dict(model_config or {}),
        "parameters": model.describe(),
        "texels": list(texels) if texels is not None else None,
        "colour_space": {"name": colour_space, "encoding": "linear",
                         "luminance_weights": list(LUMINANCE_WEIGHTS[colour_space])},
        "units": {"brdf": "sr^-1", "angles": "rad"},
        "channels": [{"name": ch, "parameter": par, "component": k, "unit": units.get(par, ""),
                      "type": "half" if dtype == np.float16 else "float"} for ch, par, k in channel_names(model.parameters)],
        **(extra or {}),
    }


def write_material(url: str, params: dict, model, model_config=None, dtype="float32", colour_space="mcallister",
                   name: str = "material") -> list[str]:
    """Write ``params`` (``name -> (V, U, C)``) as ``<name>.exr`` + ``<name>.json`` under ``url``."""
    dtype = np.dtype(dtype)
    V, U = next(iter(params.values())).shape[:2]
    desc = describe_material(model, model_config, dtype, (U, V), colour_space)
    chans = {ch: _to_float(np.asarray(params[par])[..., k], dtype) for ch, par, k in channel_names(model.parameters)}
    write_exr_channels(join(url, f"{name}.exr"), chans, {"sbrdf": json.dumps(desc)})
    import fsspec

    with fsspec.open(join(url, f"{name}.json"), "w") as f:
        json.dump(desc, f, indent=1)
    return [f"{name}.exr", f"{name}.json"]


def read_material(url: str) -> tuple[dict[str, np.ndarray], dict]:
    """A material EXR (the file, or a folder holding ``material.exr``) -> ``(params name -> (V, U, C) float64, description)``."""
    path = url if url.endswith(".exr") else join(url, "material.exr")
    chans, header = read_exr_channels(path)
    if "sbrdf" not in header:
        raise ValueError(f"{path} has no 'sbrdf' header attribute: not a material written by float-exr")
    desc = json.loads(header["sbrdf"])
    if desc.get("format") != FORMAT:
        raise ValueError(f"{path}: format {desc.get('format')!r}, expected {FORMAT!r}")
    out = {}
    for p in desc["parameters"]:
        names = [ch for ch, par, _ in channel_names([p]) if par == p["name"]]
        missing = [ch for ch in names if ch not in chans]
        if missing:
            raise ValueError(f"{path}: channels {missing} of parameter {p['name']!r} are missing (has {sorted(chans)})")
        out[p["name"]] = np.stack([chans[ch].astype(np.float64) for ch in names], axis=-1)
    return out, desc


def _to_float(x, dtype):
    info = np.finfo(dtype)
    return np.clip(np.nan_to_num(x, nan=0.0), float(info.min), float(info.max)).astype(dtype)


class FloatEXRQuantizer:
    """Float textures (exact for float32); the EXR + JSON pair is written beside them."""

    params = FLOAT_EXR

    def __init__(self, *, dtype: str = "float16", colour_space: str = "mcallister"):
        self.dtype = np.dtype(dtype)
        if self.dtype.kind != "f":
            raise ValueError(f"float-exr: dtype must be float16 or float32, not {dtype}")
        self.colour_space = colour_space

    def encode(self, params, model) -> Encoded:
        enc = Encoded()
        info = np.finfo(self.dtype)
        for name, x in params.items():
            enc.textures[name] = x.clip(float(info.min), float(info.max)).astype(self.dtype)
            enc.scale[name] = np.ones(x.shape[-1])
            enc.bias[name] = np.zeros(x.shape[-1])
        return enc

    def decode(self, textures, scale, bias, model):
        return {name: t.astype(np.float64) * scale[name] + bias[name] for name, t in textures.items()}

    def write_files(self, art, textures, scale, bias, model):
        params = {p.name: textures[p.name] for p in model.parameters}
        files = write_material(art.url, params, model, art.attrs.get("model_config", {}), self.dtype, self.colour_space)
        return {"files": files, "colour_space": self.colour_space}
