"""Export: a fitted or quantized material in a format other tools read (glTF, MaterialX, USD, Mitsuba, EXR sets).

Exporter protocol (:class:`sbrdf_core.contracts.Exporter`):

- ``convert(material) -> {name: lazy (V, U, C) array}``: the exported
  parameter maps, computed per texel tile like any node's arrays (a
  conversion fit to the GGX model glTF uses runs here), and optionally
  ``error`` ``(V, U, 1)``: the conversion's relative error per texel.
- ``write(directory, maps, material) -> attrs``: called once every chunk is
  written, with the maps read back as NumPy and the artifact's directory on
  local disk (the node refuses a remote store before computing); writes the
  files beside the arrays and returns attributes, at least ``{"files": [...]}``.

With the optional ``samples`` input (the SampledReflectance the material
was fitted to, on the same texel grid), ``material.samples`` is that artifact:
an exporter that can fits its format's model to the measured samples instead
of converting the fitted parameters (``gltf``'s ``source: samples``).

The arrays are stored (``maps/<name>``, ``error``) so that an export resumes
like any node and its error can be inspected per texel (``sbrdf info``); the
files are what a user hands on.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from ..artifacts import Exported, ParamMaps, SampledReflectance, TextureSet
from ..contracts import Exporter
from ..errors import SbrdfError
from .base import BuildContext, NodeKind, Output, Port
from .render import load_material


class Export(NodeKind):
    name = "Export"
    doc = "Write a material in another tool's format (files beside the arrays) with the conversion's error per texel."
    inputs = (Port("material", (ParamMaps, TextureSet), "fitted or quantized material"),
              Port("samples", (SampledReflectance,), "the reflectance samples the material was fitted to, for an "
                   "exporter that fits its format's model to them (gltf's source: samples)", optional=True))
    output = Exported
    plugin_category = "exporter"

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        directory = _local_directory(ctx.url)  # refused before anything computes, not after the conversion
        art = ctx.inputs["material"]
        material = load_material(ctx.registry, art)
        samples = ctx.inputs.get("samples")
        if samples is not None:
            if list(samples.attrs["texels"]) != list(material.texels):
                raise SbrdfError(f"node {ctx.node!r}: its samples have {list(samples.attrs['texels'])} texels and its "
                                 f"material {list(material.texels)}: give it the samples the material was fitted to")
            material = dataclasses.replace(material, samples=samples)
        exporter: Exporter = ctx.plugin
        maps: dict[str, Any] = dict(exporter.convert(material))
        error = maps.pop("error", None)
        arrays = {f"maps/{k}": v.astype(np.float32) for k, v in maps.items()}
        if error is not None:
            arrays["error"] = error.astype(np.float32)

        def finalize(out):
            t0 = time.perf_counter()
            values = {k: out.read(f"maps/{k}") for k in maps}
            attrs = dict(exporter.write(directory, values, material) or {})
            attrs["write_s"] = time.perf_counter() - t0
            if error is not None:
                e = out.read("error")
                finite = e[np.isfinite(e)]
                attrs.update(error_mean=float(finite.mean()) if finite.size else None,
                             error_p95=float(np.percentile(finite, 95)) if finite.size else None,
                             error_max=float(finite.max()) if finite.size else None,
                             error_nonfinite=int(e.size - finite.size))
            return attrs

        assert ctx.spec is not None  # an Export node always has its plugin
        return Output(arrays=arrays, attrs={"exporter": ctx.plugin_name, "material": material.source,
                                            "model": material.model.name, "texels": list(material.texels),
                                            "size_mm": list(material.size_mm)},
                      finalize=finalize)


def _local_directory(url: str) -> str:
    """The artifact's directory on local disk: exporters write ordinary files that other tools open."""
    import fsspec
    from fsspec.implementations.local import LocalFileSystem

    fs, path = fsspec.core.url_to_fs(url)
    if not isinstance(fs, LocalFileSystem):
        raise SbrdfError(f"Export writes files for other tools and needs a store on local disk, not {url}")
    return path
