"""exr-set: one float EXR per model parameter and a JSON sidecar, for anyone writing their own shader.

No conversion: the files hold the fitted model's own parameter maps, at
float32, so a shader that implements the model (its GLSL is in the sidecar
and in ``brdf.glsl``) reproduces what the project renders.  The sidecar
(``material.json``, format ``sbrdf-exr-set/1``) says, per file, which
parameter it holds, its channels, unit, bounds and meaning, plus the model's
name and configuration, the texel grid and the sample's size in mm, and the
uv convention.  Each EXR also carries its own entry in the header attribute
``sbrdf`` so a file is self-describing on its own.  ``convert`` returns the
maps unchanged and no ``error`` (there is none).
"""

from __future__ import annotations

import json
import os

import numpy as np

from sbrdf_core.io import write_exr_channels

from .common import exr_channels, model_config, texel_grid, write_json
from .declarations import EXR_SET

FORMAT = "sbrdf-exr-set/1"


class EXRSetExporter:
    """The model's parameter maps, one EXR each, plus ``material.json`` and ``brdf.glsl``."""

    params = EXR_SET

    def __init__(self, *, colour_space: str = "mcallister", glsl: bool = True):
        self.colour_space = colour_space
        self.glsl = glsl

    def convert(self, material):
        return {p.name: material.params[p.name] for p in material.model.parameters}

    def describe(self, material, maps) -> dict:
        from sbrdf_core.brdf import LUMINANCE_WEIGHTS

        model = material.model
        files = []
        for p in model.parameters:
            C = int(np.asarray(maps[p.name]).shape[-1])
            chans = list(exr_channels(p.name, np.zeros((1, 1, C))))
            files.append({"file": f"{p.name}.exr", "parameter": p.name, "channels": chans, "components": C,
                          "unit": p.unit, "bounds": [float(b) for b in p.bounds], "default": p.default,
                          "scope": p.scope, "doc": p.doc, "type": "float"})
        desc = {
            "format": FORMAT,
            "model": model.name,
            "model_config": model_config(material),
            "model_doc": (type(model).__doc__ or "").strip() or None,
            "parameters": model.describe(),
            "files": files,
            **texel_grid(material),
            "colour_space": {"name": self.colour_space, "encoding": "linear",
                             "luminance_weights": list(LUMINANCE_WEIGHTS[self.colour_space])},
            "units": {"brdf": "sr^-1 (f_r; radiance = f_r * irradiance * cos)", "angles": "rad", "length": "mm"},
            "frame": "parameters are in the surface frame: +z the normal, +x the tangent along u, +y along v",
            "source": material.source,
        }
        if self.glsl:
            desc["glsl"] = {"file": "brdf.glsl", "call": model.glsl_call(
                "wi", "wo", {p.name: p.name for p in model.parameters}),
                "note": "wi, wo: unit vectors in the surface frame; returns f_r (RGB, sr^-1)"}
        return desc

    def write(self, directory, maps, material):
        d = directory
        desc = self.describe(material, maps)
        files = []
        for entry in desc["files"]:
            name = entry["parameter"]
            write_exr_channels(os.path.join(d, entry["file"]), exr_channels(name, maps[name]),
                               {"sbrdf": json.dumps({"format": FORMAT, "model": desc["model"], **entry})})
            files.append(entry["file"])
        if self.glsl:
            with open(os.path.join(d, "brdf.glsl"), "w") as f:
                f.write(f"// {desc['model']} {json.dumps(desc['model_config'])}: f_r in sr^-1, surface frame\n")
                f.write(material.model.glsl())
            files.append("brdf.glsl")
        files.append(write_json(d, "material.json", desc))
        return {"files": files, "format": FORMAT, "colour_space": self.colour_space}


def read_exr_set(directory: str) -> tuple[dict[str, np.ndarray], dict]:
    """An EXR set back: ``(parameter -> (V, U, C) float32, the sidecar)``."""
    from sbrdf_core.io import read_exr_channels

    with open(os.path.join(directory, "material.json")) as f:
        desc = json.load(f)
    if desc.get("format") != FORMAT:
        raise ValueError(f"{directory}: format {desc.get('format')!r}, expected {FORMAT!r}")
    out = {}
    for entry in desc["files"]:
        chans, _ = read_exr_channels(os.path.join(directory, entry["file"]))
        out[entry["parameter"]] = np.stack([np.asarray(chans[c], np.float32) for c in entry["channels"]], axis=-1)
    return out, desc
