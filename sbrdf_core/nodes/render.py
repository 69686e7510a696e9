"""Render: images of a material, as linear EXR and display PNG.

Renderer protocol (:class:`sbrdf_core.contracts.Renderer`): ``render(material)
-> RenderResult`` with a lazy or NumPy ``(H, W, 3)`` linear image.  The node
accepts fitted ParamMaps or quantized TextureSets; a TextureSet is decoded by
the quantizer that wrote it, so the renderer always sees the model and its
parameter maps (and, for renderers that emulate a texture format, the encoded
textures too).  It also accepts every kind a plugin declares renderable
(``ArtifactKind.material``, e.g. a shading map), handed over as an
:class:`~sbrdf_core.types.InputArtifact`.  Renderers that draw scenes read the scene file
themselves and may load further materials with :func:`load_material`.

A renderer that needs arrays in memory declares ``prepare(material) ->
{name: dask collection}``: the runner computes them before build, and the
renderer gets ``render(material, prepared=...)`` — building never computes.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from .. import contracts
from ..artifacts import KINDS, Images, ParamMaps, TextureSet
from ..types import InputArtifact, Material
from .base import BuildContext, NodeKind, Output, Port


def load_material(registry, art) -> Material:
    """A ParamMaps or TextureSet artifact as a :class:`Material` (parameters stay lazy)."""
    model = registry.create("brdf-model", art.attrs["model"], dict(art.attrs.get("model_config", {})))
    alpha, encoded = None, None
    if art.kind == TextureSet.kind:
        quantizer_name = art.attrs["quantizer"]
        quantizer = registry.create("quantizer", quantizer_name, {})
        names = sorted({n.split("/", 1)[1] for n in art.names() if n.startswith("textures/")})
        encoded = {"quantizer": quantizer_name, "textures": {n: art.array(f"textures/{n}") for n in names},
                   "scale": {n: art.read(f"scale/{n}") for n in names}, "bias": {n: art.read(f"bias/{n}") for n in names}}
        decoded = quantizer.decode(encoded["textures"], encoded["scale"], encoded["bias"], model)
        params = {p.name: decoded[p.name] for p in model.parameters}
        alpha = decoded.get("alpha")
    else:
        params = {p.name: art.array(f"params/{p.name}") for p in model.parameters}
    L = int((art.attrs.get("mip") or {}).get("levels", 0)) if art.kind == ParamMaps.kind else 0
    levels = [{p.name: art.array(f"mip/{l}/{p.name}") for p in model.parameters} for l in range(1, L + 1)]
    return Material(model, params, tuple(art.attrs["texels"]), tuple(art.attrs["size_mm"]), art.url, alpha, encoded,
                    levels)


def open_material(registry, url: str) -> Material:
    """:func:`load_material` of the store at ``url`` (a scene's ``materials: {x: {artifact: path}}``)."""
    from ..store import open_artifact

    return load_material(registry, open_artifact(url, (ParamMaps, TextureSet)))


def material_from(ctx: BuildContext, art) -> Material | InputArtifact:
    """The Render node's input as the renderer sees it: a :class:`Material`, or an :class:`InputArtifact`."""
    if art.kind in (ParamMaps.kind, TextureSet.kind):
        return load_material(ctx.registry, art)
    return InputArtifact(art)


class MaterialPort(Port):
    """Accepts ParamMaps, TextureSets and every kind a loaded plugin declares renderable (``ArtifactKind.material``).

    The kinds are read when asked, so a plugin's kind is accepted once a registry has loaded it.
    """

    @property  # type: ignore[override]
    def kinds(self) -> tuple:
        return (ParamMaps, TextureSet) + tuple(k for k in KINDS.values() if k.material)

    @kinds.setter
    def kinds(self, value) -> None:  # the dataclass __init__ assigns the declared tuple; the property decides
        pass


def display_exposure(image: np.ndarray) -> float:
    """Automatic exposure: the 99th percentile of finite radiance maps to 0.8."""
    finite = image[np.isfinite(image)]
    top = float(np.percentile(finite, 99)) if finite.size else 0.0
    return 0.8 / top if top > 0 else 1.0


def to_display(image: np.ndarray, exposure: float, gamma: str = "srgb") -> np.ndarray:
    """Linear radiance -> 8-bit display values (sRGB curve, or a plain 1/2.2 power)."""
    if gamma == "srgb":
        from ..io import linear_to_srgb8

        return linear_to_srgb8(image, exposure)
    x = np.clip(np.nan_to_num(image * exposure, nan=0.0), 0.0, 1.0)
    return np.round(255.0 * x ** (1 / 2.2)).astype(np.uint8)


class Render(NodeKind):
    name = "Render"
    doc = "Render a material; writes image.exr (linear) and image.png (display) beside the arrays."
    #: Plugins' renderable kinds (shading maps) are rendered with a BRDF chosen in the scene.
    inputs = (MaterialPort("material", (), "fitted or quantized material, or a kind a plugin renders (a shading map)"),)
    output = Images
    plugin_category = "renderer"

    @classmethod
    def prepare(cls, ctx: BuildContext) -> dict[str, Any]:
        """The renderer's ``prepare(material)``: what it needs in memory, computed by the runner before build."""
        prepare = contracts.optional(ctx.plugin, "prepare", "renderer")
        return dict(prepare(material_from(ctx, ctx.inputs["material"]))) if prepare is not None else {}

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        art = ctx.inputs["material"]
        material = material_from(ctx, art)
        renderer: contracts.Renderer = ctx.plugin
        if contracts.optional(renderer, "prepare", "renderer") is not None:
            result = renderer.render(material, prepared=ctx.prepared)
        else:
            result = renderer.render(material)

        def finalize(art):
            from ..io import write_exr, write_png
            from ..store import join

            t0 = time.perf_counter()
            image = art.read("image")
            exposure = result.exposure if result.exposure is not None else display_exposure(image)
            write_exr(join(art.url, "image.exr"), image)
            write_png(join(art.url, "image.png"), to_display(image, exposure, result.gamma))
            return {"files": ["image.exr", "image.png"], "write_s": time.perf_counter() - t0, "exposure": exposure,
                    "finite": bool(np.isfinite(image).all())}

        image = result.image
        if isinstance(image, np.ndarray):
            import dask.array as da

            image = da.from_array(image)
        return Output(
            arrays={"image": image.astype(np.float32)},
            attrs={"renderer": ctx.plugin_name, "material": material.source, "input_kind": art.kind,
                   "model": getattr(getattr(material, "model", None), "name", None), **result.attrs},
            finalize=finalize,
        )
