"""Render: images of a material, as linear EXR and display PNG.

Renderer protocol: ``render(material) -> RenderResult`` with a lazy
``(H, W, 3)`` linear image.  The node accepts fitted ParamMaps or quantized
TextureSets; a TextureSet is decoded by the quantizer that wrote it, so the
renderer always sees the model and its parameter maps.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..artifacts import Images, ParamMaps, TextureSet
from ..io import linear_to_srgb8, write_exr, write_png
from ..store import join
from .base import BuildContext, NodeKind, Output, Port
from .quantize import model_of


@dataclass
class Material:
    """A BRDF model plus its (lazy) per-texel parameter maps."""

    model: Any
    params: dict[str, Any]  # name -> (V, U, C) dask array
    texels: tuple[int, int]  # (U, V)
    size_mm: tuple[float, float]
    source: str = ""


@dataclass
class RenderResult:
    image: Any  # (H, W, 3) lazy linear RGB
    exposure: float | None = None  # display exposure for the PNG; None = automatic
    attrs: dict = field(default_factory=dict)


def material_from(ctx: BuildContext, art) -> Material:
    model = model_of(ctx, art)
    if art.kind == TextureSet.kind:
        quantizer = ctx.registry.create("quantizer", art.attrs["quantizer"], {})
        names = sorted({n.split("/", 1)[1] for n in art.names() if n.startswith("textures/")})
        decoded = quantizer.decode(
            {n: art.array(f"textures/{n}") for n in names},
            {n: art.read(f"scale/{n}") for n in names},
            {n: art.read(f"bias/{n}") for n in names},
            model,
        )
        params = {p.name: decoded[p.name] for p in model.parameters}
    else:
        params = {p.name: art.array(f"params/{p.name}") for p in model.parameters}
    return Material(model, params, tuple(art.attrs["texels"]), tuple(art.attrs["size_mm"]), art.url)


class Render(NodeKind):
    name = "Render"
    doc = "Render a material; writes image.exr (linear) and image.png (sRGB) beside the arrays."
    inputs = (Port("material", (ParamMaps, TextureSet), "fitted or quantized material"),)
    output = Images
    plugin_category = "renderer"

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        material = material_from(ctx, ctx.inputs["material"])
        result: RenderResult = ctx.plugin.render(material)

        def finalize(art):
            t0 = time.perf_counter()
            image = art.read("image")
            exposure = result.exposure
            if exposure is None:  # auto: 99th percentile of finite radiance -> 0.8
                finite = image[np.isfinite(image)]
                top = float(np.percentile(finite, 99)) if finite.size else 0.0
                exposure = 0.8 / top if top > 0 else 1.0
            write_exr(join(art.url, "image.exr"), image)
            write_png(join(art.url, "image.png"), linear_to_srgb8(image, exposure))
            return {"files": ["image.exr", "image.png"], "write_s": time.perf_counter() - t0, "exposure": exposure,
                    "finite": bool(np.isfinite(image).all())}

        return Output(
            arrays={"image": result.image.astype(np.float32)},
            attrs={"renderer": ctx.spec.name, "material": material.source, "model": material.model.name, **result.attrs},
            finalize=finalize,
        )
