"""A scene's materials, resolved to a model and in-memory parameter maps.

Both renderers look parameters up the same way, so the CPU reference and the
GPU agree texel for texel: texel ``(i, j)`` has its centre at
``((i + ½)/U, (j + ½)/V)``, row 0 at v = 0, and textures repeat.  ``nearest``
takes the texel containing the point; ``bilinear`` blends the four nearest
centres (what ``GL_LINEAR`` with ``GL_REPEAT`` does).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_core.nodes.render import Material, open_material


@dataclass
class SceneMaterial:
    """One scene material: ``maps`` is ``(V, U, K)`` float32 in ``model.parameters`` order (K packed channels)."""

    name: str
    model: Any
    maps: np.ndarray
    alpha: np.ndarray | None  # (V, U) in [0, 1]; fragments below 0.5 are killed
    filter: str
    encoded: dict | None = None  # a TextureSet's quantizer name and NumPy textures, scale, bias
    #: A shading rule of its own instead of f_r · E · cos θ (shading maps): ``radiance(uv, wi, wo, E)`` on
    #: the CPU; ``glsl()``, ``glsl_radiance(wi, wo, E)``, ``gl_textures(ctx)``, ``gl_uniforms()`` on the GPU.
    surface: Any = None

    @property
    def anisotropic(self) -> bool:
        return bool(getattr(self.model, "anisotropic", False))

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Packed parameters ``(R, K)`` (float64) at texture coordinates ``uv (R, 2)``."""
        return sample(self.maps, uv, self.filter)

    def alive(self, uv: np.ndarray) -> np.ndarray:
        if self.alpha is None:
            return np.ones(len(uv), bool)
        return sample(self.alpha[..., None], uv, self.filter)[:, 0] >= 0.5


def sample(maps: np.ndarray, uv: np.ndarray, filter: str) -> np.ndarray:
    """Texture lookup with repeat wrapping; ``maps (V, U, K)``, ``uv (R, 2)`` -> ``(R, K)``."""
    V, U = maps.shape[:2]
    if filter == "nearest":
        i = np.floor(uv[:, 0] * U).astype(np.int64) % U
        j = np.floor(uv[:, 1] * V).astype(np.int64) % V
        return maps[j, i].astype(np.float64)
    x, y = uv[:, 0] * U - 0.5, uv[:, 1] * V - 0.5
    i0, j0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - i0)[:, None], (y - j0)[:, None]
    i1, j1 = (i0 + 1) % U, (j0 + 1) % V
    i0, j0 = i0 % U, j0 % V
    m = maps.astype(np.float64, copy=False)
    return ((1 - fy) * ((1 - fx) * m[j0, i0] + fx * m[j0, i1]) + fy * ((1 - fx) * m[j1, i0] + fx * m[j1, i1]))


def from_material(name: str, material: Material, filter: str) -> SceneMaterial:
    """Compute a (lazy) :class:`~sbrdf_core.nodes.render.Material` into packed in-memory maps."""
    import dask

    model = material.model
    arrays = [material.params[p.name] for p in model.parameters]
    extra = [material.alpha] if material.alpha is not None else []
    enc = material.encoded or {}
    tex_names = sorted(enc.get("textures", {}))
    computed = dask.compute(*arrays, *extra, *[enc["textures"][n] for n in tex_names])
    maps = np.concatenate([np.asarray(a, np.float32).reshape(a.shape[0], a.shape[1], -1) for a in computed[:len(arrays)]], -1)
    alpha = np.asarray(computed[len(arrays)], np.float32)[..., 0] if extra else None
    encoded = None
    if enc:
        encoded = {"quantizer": enc["quantizer"], "scale": enc["scale"], "bias": enc["bias"],
                   "textures": dict(zip(tex_names, (np.asarray(t) for t in computed[len(arrays) + len(extra):])))}
    return SceneMaterial(name, model, maps, alpha, filter, encoded)


def uniform(name: str, model, values: dict, filter: str = "nearest") -> SceneMaterial:
    """A 1×1 material from a model and parameter values (scalars or per-channel lists); missing ones default."""
    unknown = set(values) - {p.name for p in model.parameters}
    if unknown:
        raise SbrdfError(f"material {name!r}: unknown parameter(s) {sorted(unknown)} for model {model.name!r}; "
                         f"accepted: {[p.name for p in model.parameters]}")
    packed = []
    for p in model.parameters:
        v = np.asarray(values.get(p.name, p.default), dtype=np.float64).reshape(-1)
        if v.size not in (1, p.channels):
            raise SbrdfError(f"material {name!r}: parameter {p.name!r} needs 1 or {p.channels} values, got {v.size}")
        v = np.broadcast_to(v, (p.channels,))
        lo, hi = p.bounds
        if not np.all(np.isfinite(v)) or np.any(v < lo) or np.any(v > hi):
            raise SbrdfError(f"material {name!r}: parameter {p.name!r} = {v.tolist()} is outside its bounds [{lo}, {hi}]")
        packed.append(v)
    return SceneMaterial(name, model, np.concatenate(packed).astype(np.float32)[None, None], None, filter)


def resolve(scene, input_material: Material | None, registry) -> dict[str, SceneMaterial]:
    """Every material the scene's objects use, loaded once."""
    used = {o.material for o in scene.objects}
    out = {}
    from sbrdf_core.nodes.render import InputArtifact

    for name in sorted(used):
        ref = scene.materials[name]
        if isinstance(input_material, InputArtifact) and ref.artifact == "input":
            raise SbrdfError(f"{scene.file}: material {name!r} is the Render node's input, a "
                             f"{input_material.artifact.kind}: give it as shading_map: input with model: and params:")
        if ref.artifact == "input":
            if input_material is None:
                raise SbrdfError(f"{scene.file}: material {name!r} is the Render node's input, but there is none")
            out[name] = from_material(name, input_material, ref.filter)
        elif ref.artifact is not None:
            out[name] = from_material(name, open_material(registry, ref.artifact), ref.filter)
        else:
            model = registry.create("brdf-model", ref.model, dict(ref.model_params))
            if ref.shading is not None:
                shading = dict(ref.shading)
                if shading["store"] == "input":
                    if not isinstance(input_material, InputArtifact):
                        raise SbrdfError(f"{scene.file}: material {name!r} takes its shading map from the Render "
                                         "node's input, which is not a ShadingMap or PowerShadingMap")
                    shading["store"] = input_material.artifact.url
                out[name] = shading_mapped(name, model, ref.params, shading)
            else:
                out[name] = uniform(name, model, ref.params, ref.filter)
    return out


def shading_mapped(name: str, model, values: dict, shading: dict) -> SceneMaterial:
    """A shading map looked up with ``model`` (global parameters ``values``) chosen at render time."""
    try:
        from sbrdf_shading.surface import ShadingSurface
    except ImportError as e:  # pragma: no cover - the plugin ships with sbrdf
        raise SbrdfError(f"material {name!r}: shading maps need the sbrdf_shading plugin ({e})") from None
    base = uniform(name, model, values, "nearest")
    base.surface = ShadingSurface.open(shading["store"], model, model.unpack(base.maps.reshape(1, -1).astype(float)),
                                       shading["variant"], shading["above_max"], shading["sigma"])
    return base
