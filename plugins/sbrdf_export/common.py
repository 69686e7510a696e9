"""What the exporters share: the model's configuration, texture files, and the JSON they write."""

from __future__ import annotations

import json
import os

import numpy as np

#: How every exporter states the texel grid (the project's convention, docs/scenes.md).
UV_CONVENTION = ("texel (i, j) = (column, row) has its centre at ((i + 0.5)/U, (j + 0.5)/V); row 0 is at v = 0 "
                 "(the first row of every image file written here); u along the sample's +x, v along +y")


def model_config(material) -> dict:
    """The BRDF model's configuration (``model_params``): from the input artifact, else the model's attributes."""
    try:
        from sbrdf_core.store import open_artifact

        cfg = open_artifact(material.source).attrs.get("model_config")
        if cfg is not None:
            return dict(cfg)
    except Exception:  # an in-memory material (tests, benchmarks) has no store to read
        pass
    out = {}
    for p in getattr(type(material.model), "params", ()):
        if hasattr(material.model, p.name):
            v = getattr(material.model, p.name)
            out[p.name] = v.item() if isinstance(v, np.generic) else v
    return out


def texel_grid(material) -> dict:
    """Texel counts, sample size and texel pitch in mm, with the uv convention."""
    U, V = (int(x) for x in material.texels)
    w, h = (float(x) for x in material.size_mm)
    return {"texels": [U, V], "size_mm": [w, h], "texel_mm": [w / U if U else None, h / V if V else None],
            "uv": UV_CONVENTION}


def write_json(directory: str, name: str, obj: dict) -> str:
    os.makedirs(directory, exist_ok=True)
    with open(os.path.join(directory, name), "w") as f:
        json.dump(obj, f, indent=1)
    return name


def exr_channels(name: str, array: np.ndarray) -> dict[str, np.ndarray]:
    """EXR channel names for a ``(V, U, C)`` map: R, G, B for colour, Y for a scalar, ``<name>.<k>`` otherwise."""
    a = np.asarray(array, np.float32)
    C = a.shape[-1]
    if C == 3:
        return {c: a[..., k] for k, c in enumerate("RGB")}
    if C == 1:
        return {"Y": a[..., 0]}
    return {f"{name}.{k}": a[..., k] for k in range(C)}


def write_png(path: str, array: np.ndarray, srgb: bool) -> None:
    """A ``(V, U, C)`` map in [0, 1] as PNG: 8-bit sRGB-encoded colour, or 16-bit linear data (``srgb=False``)."""
    from sbrdf_core.io import linear_to_srgb8
    from sbrdf_core.io import write_png as _write

    a = np.nan_to_num(np.asarray(array, np.float64), nan=0.0)
    if a.shape[-1] == 1:
        a = a[..., 0]
    if srgb:
        img = linear_to_srgb8(a)
    else:
        img = np.round(np.clip(a, 0.0, 1.0) * 65535).astype(np.uint16)
    _write(path, img)
